"""``dyngi reproduce NAME``: a paper's comparison on our analog scenes, beside the paper's published figures.

A registry of experiments (:data:`EXPERIMENTS`, :func:`register_experiment`): each is one function
``fn(out_dir, quick, quiet) -> out_dir`` that runs the comparison with the shared evaluation
(:mod:`~dyngi.experiments.evaluate`) and writes the usual report (:mod:`~dyngi.experiments.report`:
metrics.csv, summary.md/.json, plots, grids, report.html) plus a table of the paper's published figures
beside ours. Where a paper publishes no figure for a quantity, the table says so; numbers are never
made up. ``quick`` runs a small version (the ``ddgi`` one in under 3 minutes on 2 CPU cores, tested in
the fast suite). Later technique issues add their experiments here.

An experiment's independent runs (its scenes, seeds or parts) go through
:func:`dyngi.experiments.cluster.run_named`: one task each on the executor of ``--cluster``, in this
process one after another by default; a run that fails on a cluster (after retries) is left out and
named in the report (experiments whose tables need every run stop with the failures named).

Experiments
-----------
``ddgi``  Majercik, Guertin, Nowrouzezahrai, McGuire, "Dynamic Diffuse Global Illumination with
          Ray-Traced Irradiance Fields", JCGT 8(2), 2019, on ``cornell-moving-light``:
          (a) ``ddgi`` against ``path`` at equal time per frame (``path`` gets ddgi's median steady frame
          time); (b) re-convergence after the Cornell light moves: ``ddgi`` converges with the light at one
          position, the light then jumps and stays; the frames (and milliseconds) until the error has come
          back to within 10 % of its excess over the converged level (our criterion; the paper gives none).
          Published figure used: Fig. 1's caption, "6 ms/frame, versus 1 min/frame" for the path-traced
          image (GeForce RTX 2080 Ti, 1920x1080, with glossy ray tracing and deferred direct shading). The
          paper publishes no equal-time error and no re-convergence time (it compares images visually).
"""
from __future__ import annotations

import contextlib
import csv
import json
import os
import sys
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import DyngiError, unknown_choice
from ..metrics import relmse
from ..techniques.base import Frame, create_technique
from .compare import execute, prepare
from .io import atomic_output_dir, check_writable
from .references.path import half_spp, reference_halves, reference_paths, reference_settings
from .report import write_outputs
from .runner import run_sequence


@dataclass(frozen=True)
class Experiment:
    name: str
    description: str
    paper: str
    fn: Callable


EXPERIMENTS: dict[str, Experiment] = {}


def register_experiment(name: str, description: str, paper: str):
    """Decorator: register ``fn(out_dir, quick, quiet) -> out_dir`` as experiment ``name``."""
    def deco(fn):
        EXPERIMENTS[name] = Experiment(name, description, paper, fn)
        return fn
    return deco


def _load_reproductions() -> None:
    """Import every module of :mod:`dyngi.experiments.reproductions`: each technique's experiments live in
    a module of their own there (``reproductions/<technique>.py``) and register themselves on import."""
    import importlib
    import pkgutil

    from . import reproductions
    for m in pkgutil.iter_modules(reproductions.__path__):
        importlib.import_module(f"{reproductions.__name__}.{m.name}")


def experiment_names() -> list[str]:
    _load_reproductions()
    return sorted(EXPERIMENTS)


def get_experiment(name: str) -> Experiment:
    _load_reproductions()
    if name not in EXPERIMENTS:
        raise unknown_choice("experiment", name, EXPERIMENTS)
    return EXPERIMENTS[name]


def run_experiment(name: str, out_dir: str, quick: bool = False, quiet: bool = True, smoke: bool = False) -> str:
    """Run experiment ``name`` into ``out_dir`` (written atomically); return its absolute path.
    ``smoke``: the ``--quick`` run at the smoke size (:func:`smoke_size`)."""
    exp = get_experiment(name)
    check_writable(out_dir)
    if smoke:
        with smoke_size(name):
            return exp.fn(os.path.abspath(out_dir), True, quiet)
    return exp.fn(os.path.abspath(out_dir), quick, quiet)


_R = "dyngi.experiments.reproductions."
SMOKE: dict[str, tuple[str, str, dict]] = {
    "ddgi": (__name__, "DDGI_QUICK", {"res": (32, 24), "frames": 3, "ref_spp": 8, "before": 3, "after": 5}),
    "adgi": (_R + "adgi", "ADGI_QUICK", {"res": (16, 12), "dt": 1.0, "hold": 2, "ref_spp": 4, "static_frames": 3,
                                         "reference": {"texels": 4, "rays_per_texel": 2}}),
    "isddgi": (_R + "isddgi", "ISDDGI_QUICK", {"scenes": ("corridor-rooms",), "res": (16, 12), "frames": 2,
                                               "ref_spp": 4}),
    "ddgi-resampling": (_R + "ddgi_resampling", "QUICK", {"scenes": ("cornell-static",), "res": (16, 9),
                                                          "max_frames": 6, "ref_spp": 4, "ref_spp_max": 64,
                                                          "warm_frames": 3, "steady_frames": 2, "calib_frames": 4}),
    "smcir": (_R + "smcir", "SMCIR_QUICK", {"scenes": ("maze",), "res": (16, 12), "frames": 2, "ref_spp": 4,
                                            "specs": ("mir:resampling_rate=16", "ir", "tcas:iterations=2",
                                                      "smcir:warmup=2")}),
    "vlc": (_R + "vlc", "VLC_QUICK", {"res": (16, 9), "frames": 2, "ref_spp": 4, "extras_on": ()}),
    "cdq": (_R + "cdq", "CDQ_QUICK", {"scenes_a": ("sky-pit-sun-disc",), "res_a": (16, 9), "frames_a": 4,
                                      "warmup_a": 2, "res_b": (12, 12), "pre_b": 10, "post_b": 4, "runs_b": 1,
                                      "ref_spp": 4, "bits": (32,)}),
}
"""The smoke size of every experiment: ``(module, name of its --quick configuration, the settings that
replace the quick ones)``. A smoke run takes the ``--quick`` code path at a tiny size (seconds to ~30 s on
2 cores, references included): a test that every reproduction runs end to end and writes its report,
not a measurement (its report still calls itself a quick run)."""


@contextlib.contextmanager
def smoke_size(name: str):
    """Within this block experiment ``name``'s ``--quick`` configuration holds its :data:`SMOKE` settings
    (changed in place, restored on exit; the experiment reads it when it starts). An experiment without a
    smoke size, or whose quick configuration lost a key the smoke size sets, is an error."""
    import importlib

    get_experiment(name)
    if name not in SMOKE:
        raise DyngiError(f"experiment '{name}' has no smoke size (reproduce.SMOKE); experiments with one: "
                         + ", ".join(sorted(SMOKE)))
    module, attr, settings = SMOKE[name]
    cfg = getattr(importlib.import_module(module), attr)
    missing = sorted(set(settings) - set(cfg))
    if missing:
        raise DyngiError(f"smoke size of '{name}': {module}.{attr} has no setting(s) {', '.join(missing)}")
    saved = dict(cfg)
    cfg.update(settings)
    try:
        yield cfg
    finally:
        cfg.clear()
        cfg.update(saved)


def paper_table(rows) -> str:
    """Markdown table ``quantity | paper | ours`` (``rows``: (quantity, paper text, our text))."""
    lines = ["| quantity | published (paper) | ours |", "|---|---|---|"]
    lines += [f"| {q} | {p} | {o} |" for q, p, o in rows]
    return "\n".join(lines)


def _reference_seconds(scene, t, res, spp, depth) -> float | None:
    """Render time of a cached reference (both halves), from the cache metadata; None if unknown."""
    total = 0.0
    for n, seed in zip(half_spp(spp), (0, 1)):
        _, js = reference_paths(scene, reference_settings(scene, t, res, n, depth, seed))
        try:
            total += float(json.loads(js.read_text())["render_seconds"])
        except (OSError, KeyError, ValueError):
            return None
    return total


# -- ddgi ---------------------------------------------------------------------------------

DDGI_QUICK = {"res": (64, 48), "frames": 8, "ref_spp": 512, "before": 8, "after": 30}
DDGI_FULL = {"res": (160, 120), "frames": 30, "ref_spp": 1024, "before": 20, "after": 90}
RECONVERGED_FRACTION = 0.1
"""Re-converged: the error's excess over its converged level is below this fraction of the excess right
after the move (our criterion; the DDGI paper gives none)."""


def reconvergence_frames(errors_after, converged: float, fraction: float = RECONVERGED_FRACTION) -> int | None:
    """Frames after the move until ``error <= converged + fraction * (errors_after[0] - converged)``.

    ``errors_after[0]`` is the first frame with the light at its new place (count 1). None if never.
    """
    e = np.asarray(errors_after, np.float64)
    excess0 = e[0] - converged
    if excess0 <= 0:
        return 1
    hit = np.nonzero(e <= converged + fraction * excess0)[0]
    return int(hit[0]) + 1 if hit.size else None


def ddgi_reconvergence(scene, res, before: int, after: int, ref_spp: int, ref_depth: int, seed: int = 0,
                       params: dict | None = None, bar=None) -> dict:
    """Converge ``ddgi`` with the scene at ``t_a``, move it to ``t_b`` (the light jumps) and measure relMSE.

    Returns ``{'t_a', 't_b', 'relmse' (per frame), 'ms' (per frame), 'before', 'converged_before',
    'converged_after', 'frames_to_reconverge', 'ms_to_reconverge'}``. The converged level after the move
    is the median of the last quarter of the frames after it.
    """
    t_a, t_b = scene.frame_time(0), 0.25 * scene.duration
    ref_a, _ = reference_halves(scene, t_a, res, ref_spp, ref_depth)
    ref_b, _ = reference_halves(scene, t_b, res, ref_spp, ref_depth)

    tech = create_technique("ddgi", scene, params or {})
    errs = []

    def on_frame(i, frame, r):
        img = np.asarray(r.image)
        errs.append(relmse(img, ref_a if i < before else ref_b) if np.all(np.isfinite(img)) else float("nan"))

    seq = run_sequence(scene, tech, 0, res, seed=seed, times=[t_a] * before + [t_b] * after, progress=bar,
                       on_frame=on_frame, keep_images=False)
    ms = seq.wall_ms
    e_after = np.asarray(errs[before:])
    tail = max(1, len(e_after) // 4)
    conv_after = float(np.median(e_after[-tail:]))
    k = reconvergence_frames(e_after, conv_after) if np.all(np.isfinite(e_after)) else None
    steady_ms = float(np.median(ms[1:])) if len(ms) > 1 else float(ms[0])
    return {"t_a": t_a, "t_b": t_b, "relmse": [float(x) for x in errs], "ms": ms, "before": before,
            "converged_before": float(np.median(errs[max(1, before - max(1, before // 4)):before])),
            "converged_after": conv_after, "frames_to_reconverge": k,
            "ms_to_reconverge": (k * steady_ms) if k is not None else None, "steady_ms": steady_ms}


def _reconvergence_plot(path, rc):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.2))
    e = np.asarray(rc["relmse"], np.float64)
    ax.semilogy(np.arange(len(e)), np.maximum(e, 1e-8), label="ddgi relMSE")
    ax.axvline(rc["before"] - 0.5, color="k", ls="--", lw=1, label="light moves")
    ax.axhline(rc["converged_after"], color="grey", ls=":", lw=1, label="converged level after the move")
    ax.set(xlabel="frame", ylabel="relMSE", title="ddgi: re-convergence after the Cornell light moves")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


@register_experiment(
    "ddgi", "DDGI (Majercik et al. 2019): equal time against path, re-convergence after the Cornell light moves",
    "Majercik, Guertin, Nowrouzezahrai, McGuire: Dynamic Diffuse Global Illumination with Ray-Traced "
    "Irradiance Fields, JCGT 8(2), 2019")
def reproduce_ddgi(out_dir: str, quick: bool = False, quiet: bool = True) -> str:
    """The ``ddgi`` experiment (module docstring); ``quick``: :data:`DDGI_QUICK`, else :data:`DDGI_FULL`."""
    cfg = DDGI_QUICK if quick else DDGI_FULL
    res = cfg["res"]
    names = ["mse", "relmse", "mape", "flip", "ssim"]
    run = prepare("cornell-moving-light", ["ddgi", "path"], out_dir, cfg["frames"], "equal-time", cfg["ref_spp"],
                  {}, names, None, False)
    scene = run["scene"]
    bar = None
    if not quiet:
        from tqdm import tqdm
        bar = tqdm(total=cfg["before"] + cfg["after"], desc="ddgi re-convergence", unit="frame", file=sys.stderr)
    # -- (a) equal time against path --
    rs = execute(run, res, seed=0, quiet=quiet)
    # -- (b) re-convergence after the light moves --
    rc = ddgi_reconvergence(scene, res, cfg["before"], cfg["after"], cfg["ref_spp"], run["ref_depth"], bar=bar)
    if bar is not None:
        bar.close()

    s = rs["summary"]
    d, p = s["ddgi"], s["path"]
    ref_s = _reference_seconds(scene, scene.frame_time(0), res, cfg["ref_spp"], run["ref_depth"])
    acc = rs["ctx"]["accounting"].get("path") or {}
    k = rc["frames_to_reconverge"]
    rows = [
        ("DDGI frame time", "6 ms/frame at 1920x1080, incl. glossy ray tracing and deferred direct shading, "
         "GeForce RTX 2080 Ti (Fig. 1)", f"{d['ms_per_frame']:.1f} ms/frame at {res[0]}x{res[1]}, CPU (llvm)"),
        ("path-traced image, same scene", "1 min/frame (Fig. 1)",
         (f"{ref_s:.1f} s/frame (Mitsuba path, {cfg['ref_spp']} spp, the reference)" if ref_s is not None
          else "reference taken from the cache (render time not recorded)")),
        ("speed-up of DDGI over the path-traced image", "~10^4 (1 min / 6 ms; Fig. 1)",
         (f"{1e3 * ref_s / max(d['ms_per_frame'], 1e-9):.3g}x" if ref_s is not None else "n/a")),
        ("error at equal time vs path", "no figure published (visual comparison, Fig. 1)",
         f"relMSE ddgi {d['mean']['relmse']:.3g} vs path {p['mean']['relmse']:.3g} "
         f"(path at {acc.get('steady_median_ratio', float('nan')):.2f}x ddgi's frame time)"),
        ("re-convergence after the light moves", "no figure published",
         (f"{k} frames ({rc['ms_to_reconverge']:.0f} ms at {rc['steady_ms']:.0f} ms/frame) to within "
          f"{100 * RECONVERGED_FRACTION:.0f}% of the excess; relMSE {rc['relmse'][rc['before']]:.3g} right after "
          f"the move -> {rc['converged_after']:.3g} converged" if k is not None else
          f"not re-converged within {cfg['after']} frames")),
    ]
    extra = "\n".join([
        f"## Beside the paper ({'quick' if quick else 'full'} run)", "",
        "DDGI: " + EXPERIMENTS["ddgi"].paper + ". Our analog: `cornell-moving-light`. Hardware, resolution "
        "and scene differ, so compare ratios and trends, not absolute numbers.", "",
        paper_table(rows), "",
        f"Re-convergence: ddgi runs {cfg['before']} frames with the light at t = {rc['t_a']:.3f} s, then the "
        f"light jumps to its place at t = {rc['t_b']:.3f} s and stays for {cfg['after']} frames "
        "(`reconvergence.csv`, `plots/reconvergence.png`).", ""])
    with atomic_output_dir(out_dir) as tmp:
        os.makedirs(os.path.join(tmp, "plots"), exist_ok=True)
        plot = os.path.join(tmp, "plots", "reconvergence.png")
        _reconvergence_plot(plot, rc)
        with open(os.path.join(tmp, "reconvergence.csv"), "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["frame", "light_time", "relmse", "wall_ms"])
            for i, (e, m) in enumerate(zip(rc["relmse"], rc["ms"])):
                w.writerow([i, rc["t_a"] if i < rc["before"] else rc["t_b"], e, m])
        write_outputs(tmp, scene, run["labels"], run["specs"], rs["results"], rs["refs"], rs["rows"], s, rs["ctx"],
                      run["names"], title=f"reproduce ddgi ({scene.name})", extra_md=extra, extra_plots=[plot])
        with open(os.path.join(tmp, "paper.json"), "w") as f:
            json.dump({"experiment": "ddgi", "quick": quick, "paper": EXPERIMENTS["ddgi"].paper,
                       "rows": [{"quantity": q, "paper": pp, "ours": o} for q, pp, o in rows],
                       "reconvergence": rc}, f, indent=1)
    return out_dir
