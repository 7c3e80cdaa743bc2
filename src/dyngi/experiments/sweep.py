"""``dyngi sweep TECHNIQUE SCENE --grid KEY=A,B,C [--grid ...] --seeds N``: a technique's error and time over a
grid of its parameters and several seeds, against the cached ground truth.

Every grid point (the cartesian product of the ``--grid`` values, first key slowest) runs with every seed
0..N-1 as one task (:func:`sweep_point`: the technique's whole sequence -- it is stateful -- then its
metrics against the references, :mod:`~dyngi.experiments.evaluate`, as ``dyngi compare`` measures them;
``Frame.seed`` is the seed, the reference is the same for all). The tasks run on the executor of
``--cluster`` (:mod:`~dyngi.experiments.cluster`): in this process one after another by default, or as
Ray tasks, after the missing references were rendered as chunk tasks
(:func:`~dyngi.experiments.reference_job.reference_job`). A task computes the same numbers wherever it runs
(it loads the scene and makes the technique afresh); only the times differ with the machine's load.

Writes into ``out_dir`` (atomically):

* ``summary.json``  settings, grid, and per grid point and seed: each metric's mean over the frames, |E|
                    and |E'| (SMC-IR Sec. 5.2), ms and Mrays per steady frame, the task's wall time, NaN/Inf
                    pixels; per point the mean and standard deviation over seeds; the best settings per
                    metric (lowest mean over seeds; SSIM highest) and the fastest; the failed tasks by name
                    with their error (after the executor's retries; the rest is written regardless);
* ``metrics.csv``   one row per grid point x seed x frame;
* ``summary.md`` and ``report.html`` (self-contained) with the table, the best settings and
* ``plots/error_vs_<key>.png``: every metric (and ms/frame) against each swept key, one line per
  combination of the other keys, error bars one standard deviation over seeds.
"""
from __future__ import annotations

import csv
import html
import itertools
import json
import os
import time

import numpy as np

from ..errors import DyngiError
from ..scene import load_scene
from ..techniques.base import create_technique, get_technique, resolve_params
from . import cluster
from .cluster import SceneRef, failed
from .evaluate import LABELS, check_metric_names, collect_references, evaluate_sequence
from .io import atomic_output_dir, check_writable, write_json
from .reference_job import reference_job
from .references.path import DEFAULT_REF_SPP, half_spp, scene_max_depth
from .report import data_uri, md_to_html
from .runner import run_sequence

DEFAULT_METRICS = ("mse", "relmse", "mape", "flip", "ssim")
HIGHER_IS_BETTER = frozenset({"ssim"})
EXTRA_COLUMNS = ("E", "E_prime")
"""Temporal errors reported beside the per-frame metrics (SMC-IR Sec. 5.2, over every pixel)."""


# -- the grid -----------------------------------------------------------------------------------------

def parse_grid(items, technique: str, fixed: dict | None = None) -> dict[str, list]:
    """``{key: [values...]}`` from ``--grid KEY=A,B,C`` texts, values parsed by the technique's ``Param`` types.

    Errors (one :class:`DyngiError` each): no ``--grid``; an item without ``=``; an empty key or value; a key
    that is not a parameter of ``technique`` (the valid ones listed); a key given twice or also fixed by
    ``--set`` (``fixed``); a value of the wrong type or out of range; a value listed twice."""
    cls = get_technique(technique)
    valid = ", ".join(sorted(cls.PARAMS)) or "(none)"
    if not items:
        raise DyngiError(f"no --grid given; sweep at least one parameter of '{technique}', e.g. --grid KEY=A,B "
                         f"(valid parameters: {valid})")
    grid: dict[str, list] = {}
    for it in items:
        text = str(it).strip()
        if "=" not in text:
            raise DyngiError(f"--grid expects KEY=V1,V2,..., got '{text}'")
        key, vals = (x.strip() for x in text.split("=", 1))
        if not key:
            raise DyngiError(f"--grid '{text}' has no parameter name before '='")
        if key not in cls.PARAMS:
            raise DyngiError(f"--grid: unknown parameter '{key}' for technique '{technique}'; valid parameters: {valid}")
        if key in grid:
            raise DyngiError(f"--grid names '{key}' twice; list all its values in one --grid {key}=A,B,...")
        if fixed and key in fixed:
            raise DyngiError(f"'{key}' is both swept (--grid) and fixed (--set); drop one")
        texts = [v.strip() for v in vals.split(",")]
        if not vals.strip() or any(not v for v in texts):
            raise DyngiError(f"--grid '{text}': empty value; give comma-separated values, e.g. {key}=A,B")
        parsed = []
        for v in texts:
            try:
                x = cls.PARAMS[key].parse(key, v)
            except DyngiError as e:
                raise DyngiError(f"--grid {key}: {e}") from None
            if x in parsed:
                raise DyngiError(f"--grid {key} lists the value {x} twice")
            parsed.append(x)
        grid[key] = parsed
    return grid


def grid_points(grid: dict[str, list]) -> list[dict]:
    """Every combination of the grid's values, as parameter dicts (the first key varies slowest)."""
    keys = list(grid)
    return [dict(zip(keys, combo)) for combo in itertools.product(*(grid[k] for k in keys))]


def point_label(technique: str, point: dict) -> str:
    """The spec of a grid point, ``ddgi:hysteresis=0.9:rays_per_probe=64``."""
    return ":".join([technique] + [f"{k}={v}" for k, v in point.items()])


# -- one task ------------------------------------------------------------------------------------------

def sweep_point(source, technique: str, params: dict, frames: int, res, seed: int, ref_spp: int, ref_depth: int,
                metrics) -> dict:
    """Run one grid point with one seed and measure it (a task; see the module docstring).

    ``source``: a :class:`~dyngi.experiments.cluster.SceneRef` (the scene is loaded afresh) or a Scene.
    Returns ``{'params', 'seed', 'mean', 'E', 'E_prime', 'ms_per_frame', 'rays_per_frame', 'stage_ms',
    'nonfinite_pixels', 'failed', 'per_frame': {metric: [...]}, 'wall_ms': [...], 'task_seconds'}``."""
    t0 = time.perf_counter()
    scene = source.load() if isinstance(source, SceneRef) else source
    tech = create_technique(technique, scene, dict(params))
    seq = run_sequence(scene, tech, frames, tuple(res), seed=seed)
    refs, _ = collect_references(scene, frames, tuple(res), ref_spp, ref_depth, tracked_spp=0)
    rows, s = evaluate_sequence(point_label(technique, params), seq, refs, list(metrics))
    return {"params": dict(params), "seed": int(seed), "mean": s["mean"], "E": s["E"], "E_prime": s["E_prime"],
            "ms_per_frame": s["ms_per_frame"], "rays_per_frame": s["rays_per_frame"], "stage_ms": s["stage_ms"],
            "nonfinite_pixels": s["nonfinite_pixels"], "failed": s["failed"],
            "per_frame": {m: [r[m] for r in rows] for m in metrics}, "wall_ms": [r["wall_ms"] for r in rows],
            "task_seconds": time.perf_counter() - t0}


# -- the job ---------------------------------------------------------------------------------------------

def run_sweep(technique: str, scene_name: str, grid_items, seeds: int, out_dir: str, frames: int = 30,
              res=(160, 120), ref_spp: int | None = None, ref_depth: int | None = None, metrics=None,
              params: dict | None = None, quiet: bool = True, executor=None, scene=None) -> str:
    """Run the sweep and write the outputs of the module docstring; return ``out_dir`` (absolute).

    ``grid_items``: ``KEY=A,B,C`` texts (:func:`parse_grid`); ``params``: fixed settings (``--set``);
    ``executor``: default :func:`~dyngi.experiments.cluster.current`. Failed tasks (after retries) are in
    ``summary.json['failures']`` and ``executor.failures``."""
    # -- everything checked before any work --
    cls = get_technique(technique)
    fixed = dict(params or {})
    grid = parse_grid(grid_items, technique, fixed)
    resolve_params(cls, fixed)
    names = check_metric_names(list(metrics) if metrics else list(DEFAULT_METRICS))
    if not (isinstance(seeds, int) and seeds >= 1):
        raise DyngiError(f"--seeds must be >= 1, got {seeds!r}")
    if not (isinstance(frames, int) and frames >= 1):
        raise DyngiError(f"--frames must be >= 1, got {frames!r}")
    spp = DEFAULT_REF_SPP if ref_spp is None else ref_spp
    half_spp(spp)
    if ref_depth is not None and not (isinstance(ref_depth, int) and (ref_depth >= 1 or ref_depth == -1)):
        raise DyngiError(f"--ref-depth must be >= 1 or -1 (unbounded), got {ref_depth!r}")
    check_writable(out_dir)
    out_dir = os.path.abspath(out_dir)
    points = [dict(fixed, **p) for p in grid_points(grid)]
    for p in points:
        resolve_params(cls, p)
    scene = scene if scene is not None else load_scene(scene_name)
    depth = scene_max_depth(scene) if ref_depth is None else ref_depth
    res = tuple(int(v) for v in res)
    ex = executor if executor is not None else cluster.current()
    try:
        source = cluster.scene_ref(scene_name if scene_name is not None else scene)
    except DyngiError:
        if not ex.in_process:
            raise
        source = scene

    # -- references (chunk tasks on a cluster), then one task per grid point and seed --
    w0 = time.perf_counter()
    tasks = [cluster.Task(f"{point_label(technique, {k: p[k] for k in grid})} seed {sd}", sweep_point,
                          (source, technique, p, frames, res, sd, spp, depth, names))
             for p in points for sd in range(seeds)]
    prog = cluster.Progress(len(tasks), f"sweep {technique} on {scene.name} ({ex.kind}, {ex.workers} worker"
                            f"{'s' if ex.workers != 1 else ''})", quiet=quiet, unit="task")
    failures_before = len(ex.failures)
    try:
        if not ex.in_process:
            reference_job(scene, frames, res, spp, depth, executor=ex, halves=True, progress=prog, source=source)
        outs = ex.map(tasks, progress=prog)
    finally:
        prog.close()
    seconds = time.perf_counter() - w0
    summary = summarize(technique, scene.name, grid, fixed, seeds, points, tasks, outs, names,
                        {"frames": frames, "res": list(res), "ref_spp": spp, "ref_depth": depth,
                         "cluster": ex.describe(), "seconds": seconds,
                         "job_failures": [str(f) for f in ex.failures[failures_before:]]})
    write_sweep(out_dir, summary, outs, names)
    return out_dir


def _agg(vals):
    v = np.asarray([x for x in vals if x is not None], np.float64)
    if v.size == 0:
        return {"mean": float("nan"), "std": float("nan"), "n": 0}
    return {"mean": float(np.mean(v)), "std": float(np.std(v)), "n": int(v.size)}


def summarize(technique, scene_name, grid, fixed, seeds, points, tasks, outs, names, ctx) -> dict:
    """The ``summary.json`` content (module docstring) from the tasks' outcomes."""
    per_point = []
    k = 0
    for p in points:
        runs, fails = [], []
        for _ in range(seeds):
            o = outs[k]
            (fails if failed(o) else runs).append(o if not failed(o) else {"task": o.name, "error": o.error,
                                                                            "attempts": o.attempts})
            k += 1
        cols = {m: _agg([r["mean"][m] for r in runs]) for m in names}
        cols.update({c: _agg([r[c] for r in runs]) for c in EXTRA_COLUMNS})
        per_point.append({
            "label": point_label(technique, {key: p[key] for key in grid}),
            "params": {key: p[key] for key in grid},
            "seeds": [{kk: r[kk] for kk in ("seed", "mean", "E", "E_prime", "ms_per_frame", "rays_per_frame",
                                            "stage_ms", "nonfinite_pixels", "failed", "task_seconds")}
                      for r in runs],
            "metrics": cols, "ms_per_frame": _agg([r["ms_per_frame"] for r in runs]),
            "rays_per_frame": _agg([r["rays_per_frame"] for r in runs]),
            "failed_seeds": fails,
            "nonfinite": any(r["failed"] for r in runs),
        })
    best = {}
    ok = [p for p in per_point if not p["failed_seeds"] and not p["nonfinite"] and p["seeds"]]
    for m in list(names) + list(EXTRA_COLUMNS):
        cand = [p for p in ok if np.isfinite(p["metrics"][m]["mean"])]
        if cand:
            pick = (max if m in HIGHER_IS_BETTER else min)(cand, key=lambda p: p["metrics"][m]["mean"])
            best[m] = {"label": pick["label"], "params": pick["params"], "mean": pick["metrics"][m]["mean"],
                       "std": pick["metrics"][m]["std"]}
    if ok:
        fast = min(ok, key=lambda p: p["ms_per_frame"]["mean"])
        best["ms_per_frame"] = {"label": fast["label"], "params": fast["params"],
                                "mean": fast["ms_per_frame"]["mean"], "std": fast["ms_per_frame"]["std"]}
    failures = [{"task": o.name, "error": o.error, "attempts": o.attempts} for o in outs if failed(o)]
    return {"technique": technique, "scene": scene_name, "grid": grid, "fixed": fixed, "seeds": seeds,
            "metrics": list(names), **ctx, "points": per_point, "best": best, "failures": failures}


# -- outputs ----------------------------------------------------------------------------------------------

def write_sweep(out_dir: str, summary: dict, outs, names) -> None:
    """summary.json, metrics.csv, summary.md, plots and report.html into ``out_dir`` (atomically)."""
    with atomic_output_dir(out_dir) as tmp:
        write_json(os.path.join(tmp, "summary.json"), summary)
        keys = list(summary["grid"])
        with open(os.path.join(tmp, "metrics.csv"), "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(keys + ["seed", "frame"] + list(names) + ["wall_ms"])
            for o in outs:
                if failed(o):
                    continue
                for i in range(len(o["wall_ms"])):
                    w.writerow([o["params"][k] for k in keys] + [o["seed"], i]
                               + [o["per_frame"][m][i] for m in names] + [o["wall_ms"][i]])
        plots = sweep_plots(tmp, summary, names)
        md = sweep_md(summary, names)
        with open(os.path.join(tmp, "summary.md"), "w") as f:
            f.write(md)
        _report(tmp, summary, md, plots)


def _fmt(a: dict) -> str:
    if not a or a.get("n", 0) == 0 or not np.isfinite(a["mean"]):
        return "n/a"
    return f"{a['mean']:.4g} ± {a['std']:.2g}" if a["n"] > 1 else f"{a['mean']:.4g}"


def sweep_md(summary: dict, names) -> str:
    """The summary.md text: settings, the table (mean ± std over seeds), best settings, failures."""
    keys = list(summary["grid"])
    res = summary["res"]
    cl = summary.get("cluster", {})
    lines = [f"# sweep {summary['technique']} on {summary['scene']}", "",
             f"Grid {' x '.join(f'{k} ({len(v)})' for k, v in summary['grid'].items())} x {summary['seeds']} "
             f"seed(s); {summary['frames']} frames at {res[0]}x{res[1]}; fixed settings: "
             + (", ".join(f"{k}={v}" for k, v in summary["fixed"].items()) or "defaults")
             + f". Errors against Mitsuba's `path` at {summary['ref_spp']} spp, max depth {summary['ref_depth']}; "
             "each cell is the mean over seeds ± one standard deviation of the per-seed means over the frames "
             "(lower is better except SSIM); ms/frame over the steady frames (frame 0 left out). Ran on "
             f"{cl.get('kind', 'local')} ({cl.get('workers', 1)} worker(s)) in {summary['seconds']:.1f} s.", "",
             "| " + " | ".join(keys) + " | " + " | ".join(LABELS.get(m, m) for m in names)
             + " | abs(E) | abs(E') | ms/frame | failed seeds |",
             "|" + "---|" * (len(keys) + len(names) + 4)]
    for p in summary["points"]:
        cells = [str(p["params"][k]) for k in keys]
        for m in list(names) + list(EXTRA_COLUMNS):
            v = _fmt(p["metrics"][m])
            b = summary["best"].get(m)
            cells.append(f"**{v}**" if b and b["label"] == p["label"] and len(summary["points"]) > 1 else v)
        cells.append(_fmt(p["ms_per_frame"]))
        nf = len(p["failed_seeds"])
        cells.append(("**" + str(nf) + "**") if nf else ("NaN/Inf" if p["nonfinite"] else "0"))
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "## Best settings", ""]
    for m, b in summary["best"].items():
        what = "fastest (ms/frame)" if m == "ms_per_frame" else (
            f"{LABELS.get(m, m)} ({'highest' if m in HIGHER_IS_BETTER else 'lowest'})" if m not in EXTRA_COLUMNS
            else {"E": "abs(E) (lowest)", "E_prime": "abs(E') (lowest)"}[m])
        lines.append(f"* **{what}**: `{b['label']}` ({b['mean']:.4g} ± {b['std']:.2g})")
    if summary["failures"]:
        lines += ["", "## Failed tasks", "", "After the executor's retries; every other task was measured and "
                  "written."]
        lines += [f"* `{f['task']}`: {f['error']} (after {f['attempts']} attempt(s))" for f in summary["failures"]]
    return "\n".join(lines) + "\n"


def _axis(values):
    """Numeric x positions when every value is a number (bools are categories), else categories."""
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values):
        return [float(v) for v in values], None
    return list(range(len(values))), [str(v) for v in values]


def sweep_plots(tmp: str, summary: dict, names) -> list[str]:
    """``plots/error_vs_<key>.png`` per swept key: every metric and ms/frame against the key."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    os.makedirs(os.path.join(tmp, "plots"), exist_ok=True)
    keys = list(summary["grid"])
    cols = list(names) + ["ms_per_frame"]
    paths = []
    for key in keys:
        others = [k for k in keys if k != key]
        xs, ticks = _axis(summary["grid"][key])
        fig, axes = plt.subplots(1, len(cols), figsize=(3.6 * len(cols), 3.3), squeeze=False)
        combos = sorted({tuple(p["params"][k] for k in others) for p in summary["points"]}, key=str)
        for combo in combos:
            pts = [p for p in summary["points"] if tuple(p["params"][k] for k in others) == combo]
            label = ", ".join(f"{k}={v}" for k, v in zip(others, combo)) or summary["technique"]
            for ax, m in zip(axes[0], cols):
                ys, es = [], []
                for v in summary["grid"][key]:
                    p = next(q for q in pts if q["params"][key] == v)
                    a = p["ms_per_frame"] if m == "ms_per_frame" else p["metrics"][m]
                    ys.append(a["mean"] if a["n"] else np.nan)
                    es.append(a["std"] if a["n"] > 1 else 0.0)
                ax.errorbar(xs, ys, yerr=es, marker="o", capsize=3, label=label)
        for ax, m in zip(axes[0], cols):
            ax.set(xlabel=key, ylabel="ms per frame" if m == "ms_per_frame" else LABELS.get(m, m),
                   title=("time" if m == "ms_per_frame" else LABELS.get(m, m)) + f" vs {key}")
            if ticks is not None:
                ax.set_xticks(xs)
                ax.set_xticklabels(ticks)
            if m in ("mse", "relmse"):
                ax.set_yscale("log")
            ax.grid(alpha=0.3)
        if len(combos) > 1:
            axes[0][0].legend(fontsize=7)
        fig.tight_layout()
        p = os.path.join(tmp, "plots", f"error_vs_{key}.png")
        fig.savefig(p, dpi=90)
        plt.close(fig)
        paths.append(p)
    return paths


def _report(tmp: str, summary: dict, md: str, plots) -> None:
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>dyngi sweep: "
             f"{html.escape(summary['technique'])} on {html.escape(summary['scene'])}</title><style>"
             "body{font-family:sans-serif;max-width:1400px;margin:auto}table{border-collapse:collapse}"
             "td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}img{max-width:100%}</style></head><body>",
             md_to_html(md), "<h2>Error and time against each swept parameter</h2>"]
    parts += [f"<img src='{data_uri(p, 'image/png')}'>" for p in plots]
    parts.append("<p>Numbers per grid point and seed: summary.json; per frame: metrics.csv.</p></body></html>")
    with open(os.path.join(tmp, "report.html"), "w") as f:
        f.write("\n".join(parts))


def load_summary(out_dir: str) -> dict:
    with open(os.path.join(out_dir, "summary.json")) as f:
        return json.load(f)
