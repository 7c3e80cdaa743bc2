"""IS-DDGI's probe-update time against DDGI's on the analog scenes of ``dyngi reproduce isddgi`` (the
paper's abstract: 3.29-6.64x faster probe tracing, 1.27-2.47x faster in total; our target: the update at
least 2x faster than ``ddgi``'s).

Per scene and seed both techniques (their defaults; ``--isddgi`` / ``--ddgi`` add ``key=value,...``
settings) are created in one process and stepped **alternately** frame by frame (``isddgi``, ``ddgi``,
``isddgi``, ...) over the scene's animation from t = 0, so that both see the same machine load. The update is
the four stages both report (``trace probes``, ``shade probes``, ``blend``, ``states``; IS-DDGI's allocation
is inside ``states``); the first ``--skip`` frames (frame 0 holds the warm-up and the kernel compilation)
and IS-DDGI's re-test frames (every ``reclassify_interval``: relocation reads the rays back, as ``ddgi``'s
does every frame) are left out. Printed per scene: the mean stage ms of each technique over seeds and
steady frames, the update and trace speed-ups (mean over seeds, [min-max]), probe rays, and ``uptime``
before and after; then a one-line summary per scene::

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


def run_scene(name: str, seeds, frames: int, res, skip: int, extra: dict) -> dict:
    """Both techniques stepped alternately per seed; returns per-technique stage ms and per-seed speed-ups."""
    from dyngi.scene import load_scene
    from dyngi.techniques import Frame, create_technique
    ms = {t: {s: [] for s in STAGES} for t in ("isddgi", "ddgi")}
    rays = {t: [] for t in ("isddgi", "ddgi")}
    per_seed = []
    for seed in seeds:
        sc = load_scene(name)
        techs = {t: create_technique(t, sc, extra[t]) for t in ("isddgi", "ddgi")}
        interval = int(techs["isddgi"].params["reclassify_interval"])
        seed_ms = {t: {s: [] for s in STAGES} for t in techs}
        for i in range(frames):
            t = sc.frame_time(i)
            sc.at(t)
            for tn, tech in techs.items():
                r = tech.step(Frame(i, t, sc.camera(t), res, seed=int(seed)))
                if i >= skip and i % interval:
                    for s in STAGES:
                        seed_ms[tn][s].append(r.stats["ms"].get(s, 0.0))
                    rays[tn].append(r.stats["rays"].get("trace probes", 0))
        for tn in techs:
            for s in STAGES:
                ms[tn][s] += seed_ms[tn][s]
        upd = {tn: sum(np.mean(seed_ms[tn][s]) for s in STAGES) for tn in techs}
        tr = {tn: np.mean(seed_ms[tn]["trace probes"]) for tn in techs}
        per_seed.append({"update": upd["ddgi"] / upd["isddgi"], "trace": tr["ddgi"] / tr["isddgi"]})
    return {"ms": {tn: {s: float(np.mean(v)) for s, v in d.items()} for tn, d in ms.items()},
            "rays": {tn: float(np.mean(v)) for tn, v in rays.items()}, "per_seed": per_seed}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default=None)
    ap.add_argument("--all", action="store_true", help="the full reproduction's five scenes")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--frames", type=int, default=45)
    ap.add_argument("--skip", type=int, default=2)
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
        for tn in ("isddgi", "ddgi"):
            m = r["ms"][tn]
            print(f"   {tn:7s} " + "  ".join(f"{s} {m[s]:6.1f}" for s in STAGES)
                  + f"  update {sum(m.values()):6.1f} ms  probe rays {r['rays'][tn]:.0f}")
        u = [p["update"] for p in r["per_seed"]]
        tr = [p["trace"] for p in r["per_seed"]]
        print(f"   after {time.perf_counter() - t0:.0f} s: {uptime()}")
        lines.append(f"{name}: update speed-up {np.mean(u):.2f}x [{min(u):.2f}-{max(u):.2f}], trace speed-up "
                     f"{np.mean(tr):.2f}x [{min(tr):.2f}-{max(tr):.2f}] (paper: 1.27-2.47x total, 3.29-6.64x trace; "
                     f"target 2x), rays {r['rays']['ddgi'] / max(r['rays']['isddgi'], 1):.1f}x fewer, "
                     f"seeds {','.join(map(str, seeds))}")
    print("\n".join(["", "summary:"] + lines))


if __name__ == "__main__":
    main()
