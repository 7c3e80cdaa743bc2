"""``dyngi reproduce isddgi``: IS-DDGI (Liu et al., I3D 2023) against ``ddgi`` at 256 rays per probe.

Scenes (issue 13 item 9): ``corridor-rooms`` (local light switching: the paper's best case),
``cornell-moving-box`` (local geometry change), ``tunnel-gate`` (a small change in a large grid),
``atrium-sun`` and ``cornell-moving-light`` (global change: the worst case). Per scene and technique: MSE
and FLIP against the path-traced ground truth, and ``isddgi``'s MSE and FLIP against ``ddgi``'s images;
probe rays, probe-trace ms (the ``trace probes`` stage) and probe-update ms (plan + trace + shade +
blend + states) per steady frame; their ratios beside the abstract's figures ("similar visual quality to DDGI
with a speedup of 1.27x to 2.47x in total DDGI time and 3.29x to 6.64x in probes ray tracing time").

Both techniques run their defaults at equal frames (no budget); hardware, resolution and scenes differ
from the paper's, so compare ratios and trends. ``--quick``: three scenes, few frames, small images.

Figures measured with it: docs/techniques/isddgi.md.
"""
from __future__ import annotations

import os

import numpy as np

from .. import cluster
from ..compare import execute, prepare
from ..evaluate import frame_metrics
from ..io import atomic_output_dir
from ..report import write_outputs
from ..reproduce import paper_table, register_experiment
from ._summary import write_summary

PAPER = ("Liu, Huang, Rocha, Malmros, Zhang, \"Importance-Based Ray Strategies for Dynamic Diffuse Global "
         "Illumination\", I3D 2023 (supplement only available here)")
SCENES = ("corridor-rooms", "cornell-moving-box", "tunnel-gate", "atrium-sun", "cornell-moving-light")
ISDDGI_QUICK = {"scenes": SCENES[:3], "res": (32, 24), "frames": 4, "ref_spp": 32, "seeds": (0, 1, 2)}
ISDDGI_FULL = {"scenes": SCENES, "res": (96, 72), "frames": 30, "ref_spp": 512, "seeds": (0, 1, 2),
               "scene_frames": {"corridor-rooms": 45}}
"""``scene_frames``: corridor-rooms' first light switch is at t = 1 s (frame 30); 45 frames include it and
the 14 frames after it (30 frames would show no switch at all: the best case would not be exercised).
``seeds``: every figure is the mean over these runs (issue 26: at least 3 seeds), the speed-ups also
with their [min-max]; the per-scene report is the first seed's."""
UPDATE_STAGES = ("trace probes", "shade probes", "blend", "states")
"""The probe update's stages, the same for ddgi and isddgi (isddgi's planning is timed inside "states")."""
ABSTRACT = {"trace_speedup": "3.29x-6.64x", "total_speedup": "1.27x-2.47x", "quality": "similar to DDGI"}


def _cost(seq) -> dict:
    steady, _ = seq.steady()
    rays = [st.get("rays", {}).get("trace probes", 0) for st in steady]
    ms = {k: float(np.mean([st.get("ms", {}).get(k, 0.0) for st in steady])) for k in UPDATE_STAGES}
    return {"probe_rays": float(np.mean(rays)), "trace_ms": ms["trace probes"],
            "update_ms": float(sum(ms.values())), "stage_ms": ms,
            "uniform_rays": float(np.mean([st.get("uniform_rays", 0) for st in steady])),
            "importance_rays": float(np.mean([st.get("importance_rays", 0) for st in steady]))}


def run_scene(scene_name: str, cfg: dict, out_dir: str, quiet: bool = True) -> dict:
    """Run ``isddgi`` and ``ddgi`` on one scene, write its report into ``out_dir``; return the figures."""
    names = ["mse", "flip"]
    frames = cfg.get("scene_frames", {}).get(scene_name, cfg["frames"])
    per = []
    for k, seed in enumerate(cfg.get("seeds", (0,))):
        run = prepare(scene_name, ["isddgi", "ddgi"], out_dir, frames, "equal-frames", cfg["ref_spp"], {}, names,
                      None, False)
        rs = execute(run, cfg["res"], seed=int(seed), quiet=quiet)
        s = rs["summary"]
        a, b = rs["results"]["isddgi"], rs["results"]["ddgi"]
        vs = [frame_metrics(x, y, names) for x, y in zip(a.images, b.images)]
        ci, cd = _cost(a), _cost(b)
        per.append({"seed": int(seed), "isddgi": {**s["isddgi"]["mean"], **ci}, "ddgi": {**s["ddgi"]["mean"], **cd},
                    "isddgi_vs_ddgi": {m: float(np.mean([v[m] for v in vs])) for m in names},
                    "ray_ratio": cd["probe_rays"] / max(ci["probe_rays"], 1.0),
                    "trace_speedup": cd["trace_ms"] / max(ci["trace_ms"], 1e-9),
                    "update_speedup": cd["update_ms"] / max(ci["update_ms"], 1e-9),
                    "mse_ratio": s["isddgi"]["mean"]["mse"] / max(s["ddgi"]["mean"]["mse"], 1e-30)})
        if k == 0:
            with atomic_output_dir(out_dir) as tmp:
                write_outputs(tmp, run["scene"], run["labels"], run["specs"], rs["results"], rs["refs"], rs["rows"],
                              s, rs["ctx"], run["names"], title=f"reproduce isddgi ({scene_name})")
    fig = _mean_figures(per)
    fig.update({"scene": scene_name, "frames": frames, "per_seed": per})
    return fig


def _mean_figures(per: list) -> dict:
    """The mean of the per-seed figures (nested dicts of numbers), with the speed-ups' and the MSE ratio's
    [min, max] under ``<name>_range``."""
    def mean(vals):
        if isinstance(vals[0], dict):
            return {k: mean([v[k] for v in vals]) for k in vals[0]}
        return float(np.mean(vals))
    out = {k: mean([p[k] for p in per]) for k in per[0] if k != "seed"}
    for k in ("trace_speedup", "update_speedup", "mse_ratio"):
        out[k + "_range"] = [float(min(p[k] for p in per)), float(max(p[k] for p in per))]
    out["seeds"] = [p["seed"] for p in per]
    return out


def _rng(f: dict, k: str) -> str:
    lo, hi = f.get(k + "_range", (f[k], f[k]))
    return f"{lo:.2f}-{hi:.2f}"


def _rows(figs: list) -> list:
    rows = []
    for f in figs:
        i, d = f["isddgi"], f["ddgi"]
        rows.append((f"{f['scene']}: probe-trace time", f"{ABSTRACT['trace_speedup']} faster than DDGI",
                     f"{f['trace_speedup']:.2f}x faster [{_rng(f, 'trace_speedup')}] ({i['trace_ms']:.1f} vs "
                     f"{d['trace_ms']:.1f} ms/frame); "
                     f"{f['ray_ratio']:.2f}x fewer rays ({i['probe_rays']:.0f} = {i['uniform_rays']:.0f} uniform + "
                     f"{i['importance_rays']:.0f} importance, vs {d['probe_rays']:.0f})"))
        rows.append((f"{f['scene']}: probe-update time", f"{ABSTRACT['total_speedup']} faster (total DDGI time)",
                     f"{f['update_speedup']:.2f}x [{_rng(f, 'update_speedup')}] ({i['update_ms']:.1f} vs "
                     f"{d['update_ms']:.1f} ms/frame, "
                     "plan + trace + shade + blend + states)"))
        rows.append((f"{f['scene']}: error vs ground truth", ABSTRACT["quality"],
                     f"MSE {i['mse']:.3g} vs {d['mse']:.3g} ({f['mse_ratio']:.2f}x [{_rng(f, 'mse_ratio')}]), FLIP {i['flip']:.3g} vs "
                     f"{d['flip']:.3g}; isddgi vs ddgi: MSE {f['isddgi_vs_ddgi']['mse']:.3g}, FLIP "
                     f"{f['isddgi_vs_ddgi']['flip']:.3g}"))
    return rows


@register_experiment("isddgi", "IS-DDGI vs DDGI (256 rays/probe): error, probe rays, probe-trace and update ms on "
                     "five dynamic scenes", PAPER)
def reproduce_isddgi(out_dir: str, quick: bool = False, quiet: bool = True) -> str:
    """The ``isddgi`` experiment (module docstring); ``quick``: :data:`ISDDGI_QUICK`, else :data:`ISDDGI_FULL`."""
    cfg = ISDDGI_QUICK if quick else ISDDGI_FULL
    figs = list(cluster.run_named(list(cfg["scenes"]), run_scene,   # independent runs: tasks (--cluster)
                                  [(sc, cfg, os.path.join(out_dir, sc), quiet) for sc in cfg["scenes"]],
                                  "reproduce isddgi", quiet).values())
    rows = _rows(figs)
    md = "\n".join([f"# reproduce isddgi ({'quick' if quick else 'full'} run)", "", "IS-DDGI: " + PAPER + ".",
                    f"Both techniques at their defaults, {cfg['frames']} frames "
                    f"({', '.join(f'{k}: {v}' for k, v in cfg.get('scene_frames', {}).items()) or 'every scene'}) "
                    f"at {cfg['res'][0]}x{cfg['res'][1]}, "
                    f"reference {cfg['ref_spp']} spp; means over seeds {list(cfg.get('seeds', (0,)))} "
                    "([min-max] per seed); per-scene reports (first seed) in the sub-folders. Steady frames only "
                    "(frame 0 with the warm-up is left out of the costs).", "", paper_table(rows), "",
                    *cluster.failure_notes()])
    return write_summary(out_dir, md, {
        "paper.json": {"experiment": "isddgi", "quick": quick, "paper": PAPER, "figures": figs,
                       "rows": [{"quantity": q, "paper": p, "ours": o} for q, p, o in rows]}})
