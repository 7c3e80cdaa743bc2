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
each runs at its defaults (the paper's protocol). ``--adgi`` / ``--qddgi``: extra ``key=value,...``
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
    a = ap.parse_args(argv)

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


if __name__ == "__main__":
    main()
