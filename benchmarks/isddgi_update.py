"""IS-DDGI's probe-update time against DDGI's on the analog scenes of ``dyngi reproduce isddgi`` (the
paper's abstract: 3.29-6.64x faster probe tracing, 1.27-2.47x faster in total; our target: the update at
least 2x faster than ``ddgi``'s).

Per scene and seed three runs are created in one process and stepped **round-robin** frame by frame
(``isddgi``, ``ddgi``, ``ddgi@equal-rays``, ``isddgi``, ...) over the scene's animation from t = 0, so that all
see the same machine load: both techniques at their defaults (``--isddgi`` / ``--ddgi`` add ``key=value,...``
settings) and ``ddgi`` given IS-DDGI's rays of the same frame as its ``Frame.ray_budget`` (the equal-rays row:
what is left of the speed-up when DDGI traces as few rays). **Every frame counts** (issue 40): only the first
``--skip`` frames (default 1: frame 0's kernel compilation) are left out of the times, IS-DDGI's relocation
and re-test frames included; rays are counted from frame 0. Reported apart: the *update* (the four stages
both report, ``trace probes``, ``shade probes``, ``blend``, ``states``; IS-DDGI's allocation is inside
``states``) and the *total* DDGI time (every stage of the frame, the probe query and shading included: the
abstract's "total DDGI time"). Printed per scene: the mean stage ms of each run over seeds and frames, the
update, total and trace speed-ups (mean over seeds, [min-max]), probe rays, and ``uptime`` before and
after; then a one-line summary per scene::

    nice .venv/bin/python benchmarks/isddgi_update.py [--scenes a,b] [--all] [--seeds 0,1,2] [--frames 45]
        [--res 32x24] [--isddgi K=V,...] [--ddgi K=V,...]

Defaults: the quick reproduction's three scenes (``--all``: its five), seeds 0-2, 45 frames at 32x24 (1.5 s of
animation: corridor-rooms' first light switch at 1 s and tunnel-gate's gate opening fall inside; with
``--frames 12`` both are still static). About 2 minutes for the three scenes, 4 for ``--all``, on the shared
2-core box at load ~3 with a warm kernel cache. Results go to docs/techniques/isddgi.md with the machine load.

Recorded in ``docs/techniques/isddgi.md`` ("Update and trace speed-up on the five analog scenes"), beside the
command, resolution, seeds and machine load of each run.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from common import parse_settings, uptime

STAGES = ("trace probes", "shade probes", "blend", "states")


RUNS = ("isddgi", "ddgi", "ddgi@equal-rays")


def run_scene(name: str, seeds, frames: int, res, skip: int, extra: dict) -> dict:
    """The three runs stepped round-robin per seed; returns per-run stage ms and per-seed speed-ups."""
    from dyngi.experiments.runner import SequenceResult, step_frame
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame, create_technique
    ms = {t: {s: [] for s in STAGES + ("total",)} for t in RUNS}
    rays = {t: [] for t in RUNS}
    per_seed = []
    for seed in seeds:
        sc = load_scene(name)
        techs = {"isddgi": create_technique("isddgi", sc, extra["isddgi"]),
                 "ddgi": create_technique("ddgi", sc, extra["ddgi"]),
                 "ddgi@equal-rays": create_technique("ddgi", sc, extra["ddgi"])}
        seqs = {t: SequenceResult(t) for t in RUNS}
        seed_ms = {t: {s: [] for s in STAGES + ("total",)} for t in RUNS}
        for i in range(frames):
            t = sc.frame_time(i)
            sc.at(t)
            for tn, tech in techs.items():
                budget = seqs["isddgi"].stats[i]["total_rays"] if tn == "ddgi@equal-rays" else None
                step_frame(tech, Frame(i, t, sc.camera(t), res, seed=int(seed), ray_budget=budget), seqs[tn], False)
                st = seqs[tn].stats[i]
                rays[tn].append(st.get("counted_rays") or st.get("total_rays", 0))
                if i >= skip:
                    for s in STAGES:
                        seed_ms[tn][s].append(st["ms"].get(s, 0.0))
                    seed_ms[tn]["total"].append(st.get("total_ms", 0.0))
        for tn in RUNS:
            for s in seed_ms[tn]:
                ms[tn][s] += seed_ms[tn][s]
        upd = {tn: sum(np.mean(seed_ms[tn][s]) for s in STAGES) for tn in RUNS}
        tot = {tn: np.mean(seed_ms[tn]["total"]) for tn in RUNS}
        tr = {tn: np.mean(seed_ms[tn]["trace probes"]) for tn in RUNS}
        per_seed.append({"update": upd["ddgi"] / upd["isddgi"], "total": tot["ddgi"] / tot["isddgi"],
                         "trace": tr["ddgi"] / tr["isddgi"], "total_equal_rays": tot["ddgi@equal-rays"] / tot["isddgi"]})
    return {"ms": {tn: {s: float(np.mean(v)) for s, v in d.items()} for tn, d in ms.items()},
            "rays": {tn: float(np.mean(v)) for tn, v in rays.items()}, "per_seed": per_seed}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default=None)
    ap.add_argument("--all", action="store_true", help="the full reproduction's five scenes")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--frames", type=int, default=45)
    ap.add_argument("--skip", type=int, default=1, help="frames left out of the times (frame 0: compilation)")
    ap.add_argument("--res", default="32x24")
    ap.add_argument("--isddgi", default=None)
    ap.add_argument("--ddgi", default=None)
    a = ap.parse_args(argv)
    from dyngi.experiments.reproductions.isddgi import SCENES
    scenes = a.scenes.split(",") if a.scenes else list(SCENES if a.all else SCENES[:3])
    seeds = [int(s) for s in a.seeds.split(",")]
    res = tuple(int(x) for x in a.res.split("x"))
    extra = {"isddgi": parse_settings(a.isddgi), "ddgi": parse_settings(a.ddgi)}
    lines = []
    for name in scenes:
        up0, t0 = uptime(), time.perf_counter()
        r = run_scene(name, seeds, a.frames, res, a.skip, extra)
        print(f"== {name}  (before: {up0})")
        for tn in RUNS:
            m = r["ms"][tn]
            print(f"   {tn:16s} " + "  ".join(f"{s} {m[s]:6.1f}" for s in STAGES)
                  + f"  update {sum(m[s] for s in STAGES):6.1f} ms  total {m['total']:6.1f} ms  rays/frame "
                  f"{r['rays'][tn]:.0f} (counted, from frame 0)")
        f = {k: [p[k] for p in r["per_seed"]] for k in r["per_seed"][0]}
        print(f"   after {time.perf_counter() - t0:.0f} s: {uptime()}")
        rng = lambda v: f"{np.mean(v):.2f}x [{min(v):.2f}-{max(v):.2f}]"    # noqa: E731
        lines.append(f"{name}: total speed-up {rng(f['total'])} (paper: 1.27-2.47x), update {rng(f['update'])}, "
                     f"trace {rng(f['trace'])} (paper: 3.29-6.64x), total at equal rays {rng(f['total_equal_rays'])}; "
                     f"rays {r['rays']['ddgi'] / max(r['rays']['isddgi'], 1):.1f}x fewer; every frame after "
                     f"{a.skip}, seeds {','.join(map(str, seeds))}")
    print("\n".join(["", "summary:"] + lines))


if __name__ == "__main__":
    main()
