"""ADGI's probe-sampling time against Q-DDGI's at a large probe grid (the paper's Table 4 claim:
probe sampling 10.97 vs 22.3 ms on Bistro, about 1/2).

Both techniques are created once in one process on ``tunnel-gate`` with ``probe_counts`` (default
``32,24,128`` = 98,304 probes), started at ``--t0`` (default 1.5 s: the gate is opening), and then stepped
**alternately** frame by frame (``adgi``, ``qddgi``, ``adgi``, ...), so that both see the same machine load.
Per frame: ADGI's probe sampling is its stages P + S + D (Table 4's "probe sampling"), Q-DDGI's its update
stages trace + shade + blend + states. The first ``--skip`` frames of each (the warm-up and kernel
compilation) are left out; the medians of the others are printed, with ``uptime`` before and after, and a
one-line summary at the end::

    nice .venv/bin/python benchmarks/adgi_probe_sampling.py [--counts 32,24,128] [--frames 10] [--res 64x48]
        [--equal-rays] [--adgi K=V,...] [--qddgi K=V,...]

``--equal-rays``: ADGI's ray budget is Q-DDGI's rays of the same frame (Q-DDGI steps first); without it
each runs at its defaults (the paper's protocol).

``--scaling 8,6,24:16,12,48:24,18,96:32,24,136`` (the scaling curve, ADGI's Sec. 7 claim): ADGI and Q-DDGI at
each grid (1,152 to 104,448 probes), all eight stepped round-robin in one process
(:func:`dyngi.experiments.runner.run_round_robin`, each at its defaults), every frame timed; per technique and
grid the probe work per frame (:func:`dyngi.experiments.report.probe_work_ms`: every stage but primary
shading), median over the frames after ``--skip`` and the mean over all frames; a markdown table and
``scaling.png`` (:func:`dyngi.experiments.report.scaling_plot`) under ``--out``. ``--adgi`` / ``--qddgi``: extra ``key=value,...``
settings (e.g. ``--adgi impl=device``). At the defaults it takes about a minute on the shared 2-core box
at load 2-4 with a warm kernel cache (the first frame of each, with the warm-up, 5-25 s; the others
0.4-1 s). Results go to docs/techniques/adgi.md with the machine load.

Recorded in ``docs/techniques/adgi.md`` ("probe sampling at 98,304 probes"), beside the command, resolution,
seeds and machine load of each run.
"""
from __future__ import annotations

import argparse
import statistics
import time

from common import parse_settings, uptime

ADGI_STAGES = ("P", "S", "D")
QDDGI_STAGES = ("trace probes", "shade probes", "blend", "states")


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--counts", default="32,24,128", help="probe_counts of both techniques (default 98,304 probes)")
    ap.add_argument("--frames", type=int, default=10, help="frames per technique (the first --skip are left out)")
    ap.add_argument("--skip", type=int, default=2, help="first frames left out (warm-up, compilation)")
    ap.add_argument("--res", default="64x48")
    ap.add_argument("--t0", type=float, default=1.5, help="start time in seconds (the gate is opening)")
    ap.add_argument("--adgi", default="", help="extra adgi settings, key=value,...")
    ap.add_argument("--qddgi", default="", help="extra qddgi settings, key=value,...")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--equal-rays", action="store_true",
                    help="adgi gets qddgi's rays of the same frame as its budget (qddgi steps first)")
    ap.add_argument("--scaling", default="", help="grids 'nx,ny,nz:nx,ny,nz:...': the scaling curve (docstring)")
    ap.add_argument("--out", default="out/adgi_scaling", help="--scaling: where the table and plot go")
    a = ap.parse_args(argv)
    if a.scaling:
        return scaling(a)

    from dyngi.scene import load_scene
    from dyngi.techniques.base import Frame, create_technique

    res = tuple(int(x) for x in a.res.split("x"))
    print("uptime before:", uptime(), flush=True)
    sc = load_scene("tunnel-gate")
    techs = {}
    order = (("qddgi", a.qddgi), ("adgi", a.adgi)) if a.equal_rays else (("adgi", a.adgi), ("qddgi", a.qddgi))
    for name, extra in order:
        t0 = time.perf_counter()
        techs[name] = create_technique(name, sc, {"probe_counts": a.counts, **parse_settings(extra)})
        print(f"{name}: created in {time.perf_counter() - t0:.1f} s", flush=True)
    n_probes = techs["adgi"].volume.n_probes
    sampling = {n: [] for n in techs}
    rays = {n: [] for n in techs}
    for i in range(a.frames):
        t = a.t0 + sc.frame_time(i)
        budget = None
        for name, tech in techs.items():
            sc.at(t)
            w0 = time.perf_counter()
            r = tech.step(Frame(i, t, sc.camera(t), res, seed=a.seed,
                                ray_budget=budget if name == "adgi" else None))
            if a.equal_rays and name == "qddgi":
                budget = r.stats.get("total_rays", 0)
            wall = 1e3 * (time.perf_counter() - w0)
            ms = r.stats["ms"]
            keys = ADGI_STAGES if name == "adgi" else QDDGI_STAGES
            s = sum(ms.get(k, 0.0) for k in keys)
            print(f"frame {i} {name}: probe sampling {s:.1f} ms ("
                  + ", ".join(f"{k} {ms.get(k, 0.0):.1f}" for k in keys)
                  + f"), frame {wall:.0f} ms, {r.stats.get('total_rays', 0)} rays", flush=True)
            if i >= a.skip:
                sampling[name].append(s)
                rays[name].append(r.stats.get("total_rays", 0))
    after = uptime()
    print("uptime after:", after)
    med = {n: statistics.median(v) for n, v in sampling.items()}
    ratio = med["adgi"] / max(med["qddgi"], 1e-9)
    print(f"SUMMARY tunnel-gate {n_probes} probes ({a.counts}), {a.res}, frames {a.skip}-{a.frames - 1} alternating"
          f"{', adgi at qddgi rays' if a.equal_rays else ', each at its defaults'}: "
          f"adgi P+S+D {med['adgi']:.1f} ms ({statistics.median(rays['adgi']):.0f} rays/frame), qddgi sampling "
          f"{med['qddgi']:.1f} ms ({statistics.median(rays['qddgi']):.0f} rays/frame), adgi/qddgi = {ratio:.2f} "
          f"(target <= 0.5); load after: {after.split('load average:')[-1].strip()}")
    return {"median_ms": med, "ratio": ratio, "probes": n_probes}


def scaling(a) -> dict:
    """``--scaling``: ADGI and Q-DDGI at every grid, stepped round-robin in one process (module docstring)."""
    import os

    import numpy as np

    from dyngi.experiments.report import probe_work_ms, scaling_plot
    from dyngi.experiments.runner import run_round_robin
    from dyngi.scene import load_scene
    from dyngi.techniques.base import create_technique

    res = tuple(int(x) for x in a.res.split("x"))
    grids = [g.strip() for g in a.scaling.split(":") if g.strip()]
    print("uptime before:", uptime(), flush=True)
    sc = load_scene("tunnel-gate")
    techs, meta = {}, {}
    for g in grids:
        for name, extra in (("adgi", a.adgi), ("qddgi", a.qddgi)):
            lb = f"{name}@{g}"
            techs[lb] = create_technique(name, sc, {"probe_counts": g, **parse_settings(extra)})
            meta[lb] = (name, techs[lb].volume.n_probes)
    outs, errors = run_round_robin(sc, techs, a.frames, res, seed=a.seed, t0=a.t0)
    after = uptime()
    rows = []
    for lb, seq in outs.items():
        if lb in errors:
            print(f"{lb}: failed: {errors[lb]}")
            continue
        work = [probe_work_ms(st["ms"]) or 0.0 for st in seq.stats]
        steady = work[a.skip:] or work
        name, n = meta[lb]
        rows.append({"technique": name, "probes": n, "grid": lb.split("@")[1], "probe_ms": statistics.median(steady),
                     "probe_ms_lo": float(np.min(steady)), "probe_ms_hi": float(np.max(steady)),
                     "mean_all_frames": float(np.mean(work)),
                     "rays": statistics.median([st.get("counted_rays", 0) for st in seq.stats[a.skip:] or seq.stats])})
    lines = [f"tunnel-gate, {a.res}, frames {a.skip}-{a.frames - 1} (median) and all frames (mean), round-robin in "
             f"one process, each at its defaults; load before/after: {after.split('load average:')[-1].strip()}", "",
             "| probes | grid | adgi probe work ms (median [min-max]) | qddgi probe work ms | adgi / qddgi | "
             "mean over all frames, adgi / qddgi | rays per frame adgi / qddgi |", "|---|---|---|---|---|---|---|"]
    for g in grids:
        ad = next((r for r in rows if r["grid"] == g and r["technique"] == "adgi"), None)
        qd = next((r for r in rows if r["grid"] == g and r["technique"] == "qddgi"), None)
        if ad is None or qd is None:
            continue
        lines.append(f"| {ad['probes']} | {g} | {ad['probe_ms']:.1f} [{ad['probe_ms_lo']:.1f}-{ad['probe_ms_hi']:.1f}] | "
                     f"{qd['probe_ms']:.1f} [{qd['probe_ms_lo']:.1f}-{qd['probe_ms_hi']:.1f}] | "
                     f"{ad['probe_ms'] / max(qd['probe_ms'], 1e-9):.2f} | "
                     f"{ad['mean_all_frames']:.0f} / {qd['mean_all_frames']:.0f} | {ad['rays']:.0f} / {qd['rays']:.0f} |")
    os.makedirs(a.out, exist_ok=True)
    table = "\n".join(lines)
    open(os.path.join(a.out, "scaling.md"), "w").write(table + "\n")
    plot = scaling_plot(rows, os.path.join(a.out, "scaling.png"))
    print(table)
    print("uptime after:", after)
    print("plot:", plot)
    return {"rows": rows, "table": table}


if __name__ == "__main__":
    main()
