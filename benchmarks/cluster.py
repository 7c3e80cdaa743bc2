"""Speed-up of `dyngi reference` and `dyngi sweep` on 1, 2 and 4 local Ray workers against the serial run.

    .venv/bin/python benchmarks/cluster.py [--frames 4] [--spp 512] [--res 160x120] [--workers 1,2,4]
                                           [--sweep-frames 10] [--repeat K] [--out bench-cluster.json]

Every configuration runs in a fresh process (its own Dr.Jit thread pool, its own Ray instance) on a fresh
reference cache, in one run of this script, so the serial baselines and the cluster runs see the same
machine state; `uptime` is printed before and after. Measured:

reference  the job of `dyngi reference SCENE --frames F --spp S` (two seeded halves per frame):
           serial       in-process, Dr.Jit on every core (what `--cluster local` does);
           serial-1t    in-process, Dr.Jit pinned to 1 thread (the work of one worker, no cluster);
           ray-N        `reference_job` on a local Ray instance of N CPUs, one task per chunk (about two per
                        worker), each task 1 CPU and 1 Dr.Jit thread; the Ray start is timed separately.
sweep      `dyngi sweep ddgi SCENE --grid hysteresis=0.9,0.97 --grid rays_per_probe=64,256 --seeds 2`
           with its references cached first (so the technique tasks are what is timed): serial (local
           executor, every core) and ray-N as above.

Overhead of the cluster = ray-1 job time - serial-1t time (the same work on one thread), as a fraction of
the job. Speed-up of ray-N = ray-1 / ray-N (ideal N while N <= cores).

Recorded in ``docs/cluster.md`` ("Measured"), beside the command, resolution, seeds and machine load of each
run.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

from common import uptime

SCENE = "cornell-moving-light"
GRID = ["hysteresis=0.9,0.97", "rays_per_probe=64,256"]


def _one(cfg: dict) -> dict:
    """Run one configuration in this (fresh) process; return its timings."""
    import logging

    os.environ["DYNGI_CACHE"] = cfg["cache"]
    from dyngi.backend import dr
    from dyngi.experiments.runner import parse_res
    from dyngi.scene import load_scene

    res = parse_res(cfg["res"])
    out = {"name": cfg["name"]}
    ex = None
    if cfg["mode"] == "serial-1t":
        dr.set_thread_count(1)
    if cfg["mode"].startswith("ray"):
        import ray

        from dyngi.experiments.cluster import RayExecutor

        t0 = time.perf_counter()
        ray.init(num_cpus=cfg["workers"], include_dashboard=False, logging_level=logging.WARNING,
                 log_to_driver=False)
        ex = RayExecutor("auto")
        out["start_s"] = time.perf_counter() - t0
        out["workers"] = ex.workers
    out["threads"] = dr.thread_count()
    scene = load_scene(SCENE)
    if cfg["job"] == "reference":
        from dyngi.experiments.reference_job import reference_job
        from dyngi.experiments.references.path import fill_reference_cache

        t0 = time.perf_counter()
        if ex is None:
            fill_reference_cache(scene, cfg["frames"], res, cfg["spp"], 12, halves=True)
        else:
            reference_job(scene, cfg["frames"], res, cfg["spp"], 12, executor=ex, halves=True)
            out["failures"] = [str(f) for f in ex.failures]
        out["job_s"] = time.perf_counter() - t0
    else:
        from dyngi.experiments.cluster import LocalExecutor
        from dyngi.experiments.references.path import fill_reference_cache
        from dyngi.experiments.sweep import run_sweep

        fill_reference_cache(scene, cfg["frames"], res, cfg["spp"], 12, halves=True)   # cached before timing
        t0 = time.perf_counter()
        run_sweep("ddgi", SCENE, GRID, cfg["seeds"], os.path.join(cfg["cache"], "sweep-out"), frames=cfg["frames"],
                  res=res, ref_spp=cfg["spp"], metrics=["mse", "relmse", "mape"],
                  executor=ex if ex is not None else LocalExecutor())
        out["job_s"] = time.perf_counter() - t0
        if ex is not None:
            out["failures"] = [str(f) for f in ex.failures]
    if ex is not None:
        ex.close()
        import ray
        ray.shutdown()
    return out


def _run(cfg: dict) -> dict:
    r = subprocess.run([sys.executable, __file__, "--one", json.dumps(cfg)], capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"{cfg['name']} failed:\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--one", help=argparse.SUPPRESS)
    p.add_argument("--frames", type=int, default=4, help="reference frames (default 4)")
    p.add_argument("--spp", type=int, default=512, help="reference spp per frame (two halves; default 512)")
    p.add_argument("--res", default="160x120")
    p.add_argument("--workers", default="1,2,4")
    p.add_argument("--sweep-frames", type=int, default=10)
    p.add_argument("--sweep-res", default="64x48")
    p.add_argument("--sweep-ref-spp", type=int, default=64)
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--skip", default="", help="comma-separated jobs to skip: reference, sweep")
    p.add_argument("--repeat", type=int, default=1,
                   help="run the whole list this many times, interleaved, and report each run's median "
                        "(the load of a shared machine drifts between runs)")
    p.add_argument("--out", default=None, help="also write the results as JSON here")
    a = p.parse_args(argv)
    if a.one:
        print(json.dumps(_one(json.loads(a.one))))
        return 0
    workers = [int(x) for x in a.workers.split(",") if x.strip()]
    skip = set(a.skip.split(","))
    print(f"cores: {os.cpu_count()}; before: {uptime()}", flush=True)
    results = {"cores": os.cpu_count(), "uptime_before": uptime(), "args": vars(a), "runs": []}
    warm = tempfile.mkdtemp(prefix="dyngi-bench-warm-")          # Dr.Jit's kernel cache, warmed once
    _run({"name": "warm-up", "mode": "serial", "job": "reference", "frames": 1, "spp": 8, "res": a.res,
          "cache": warm})
    jobs = []
    if "reference" not in skip:
        base = {"job": "reference", "frames": a.frames, "spp": a.spp, "res": a.res}
        jobs += [dict(base, name="reference serial", mode="serial"),
                 dict(base, name="reference serial-1t", mode="serial-1t")]
        jobs += [dict(base, name=f"reference ray-{n}", mode="ray", workers=n) for n in workers]
    if "sweep" not in skip:
        base = {"job": "sweep", "frames": a.sweep_frames, "spp": a.sweep_ref_spp, "res": a.sweep_res,
                "seeds": a.seeds}
        jobs += [dict(base, name="sweep serial", mode="serial")]
        jobs += [dict(base, name=f"sweep ray-{n}", mode="ray", workers=n) for n in workers]
    for rep in range(a.repeat):
        for cfg in jobs:
            cfg = dict(cfg, cache=tempfile.mkdtemp(prefix="dyngi-bench-"))
            r = _run(cfg)
            r["repeat"] = rep
            results["runs"].append(r)
            print(f"{r['name']:<22} job {r['job_s']:7.1f} s" + (f"  (Ray start {r['start_s']:.1f} s, "
                  f"{r['workers']} workers)" if "start_s" in r else f"  ({r['threads']} Dr.Jit threads)")
                  + f"  [{uptime().split('load average:')[-1].strip()}]", flush=True)
    results["uptime_after"] = uptime()
    print(f"after: {results['uptime_after']}")
    by = {}
    for r in results["runs"]:      # the median run of each configuration
        by.setdefault(r["name"], []).append(r)
    by = {k: sorted(v, key=lambda r: r["job_s"])[len(v) // 2] for k, v in by.items()}
    lines = ["", "| job | run | seconds | speed-up vs ray-1 | ideal | vs serial |", "|---|---|---|---|---|---|"]
    for job in ("reference", "sweep"):
        one, ser = by.get(f"{job} ray-1"), by.get(f"{job} serial")
        for name, r in by.items():
            if not name.startswith(job):
                continue
            n = r.get("workers")
            sp = f"{one['job_s'] / r['job_s']:.2f}x" if one and n else ""
            vs = f"{ser['job_s'] / r['job_s']:.2f}x" if ser else ""
            lines.append(f"| {job} | {name.split(' ', 1)[1]} | {r['job_s']:.1f} | {sp} | {n or ''} | {vs} |")
        if one and f"{job} serial-1t" in by:
            s1 = by[f"{job} serial-1t"]["job_s"]
            ov = (one["job_s"] - s1) / one["job_s"]
            results[f"{job}_overhead"] = ov
            lines.append(f"\n{job}: cluster overhead (ray-1 - serial-1t) = {one['job_s'] - s1:.1f} s = "
                         f"{100 * ov:.1f}% of the {one['job_s']:.0f} s job; Ray start {one['start_s']:.1f} s (once)")
    print("\n".join(lines))
    if a.out:
        with open(a.out, "w") as f:
            json.dump(results, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
