"""Steady frame time of techniques against Mitsuba's ``path`` at 1 spp, measured in the same run.

For each technique spec: ``--frames`` frames of the scene (static camera, so techniques with temporal
state reach their steady state), the median wall time of the frames after the first ``--skip`` (kernel
compilation, probe warm-up); Mitsuba's ``path`` integrator (``max_depth`` 12, 1 spp, same resolution)
is timed right before and after each technique and its median is the denominator, so a change of the
machine's load between techniques shows in the reference too. Prints one Markdown row per technique
(a technique that fails prints its error in the row and the run goes on) and the machine load
(``os.getloadavg``) before and after. ``--techniques all``: every registered technique at its defaults but the offline references
(:data:`OFFLINE`; name one to include it).
The scene: ``--scene`` (or the first argument), a built-in name or a Mitsuba XML file; by default the
real Cornell box of ``../shared/scenes`` (the performance table: 320x180 on a real scene).

    .venv/bin/python benchmarks/frame_time.py --scene ../shared/scenes/cornell-box/scene_mi3.xml \\
        --techniques all --res 320x180 --frames 12 --skip 4

Recorded in ``docs/performance.md`` ("Steady frame time at 320x180 on a real scene"), beside the command,
resolution, seeds and machine load of each run.
"""
from __future__ import annotations

import argparse
import os
import time
import traceback

import numpy as np

OFFLINE = ("probes-reference",)
"""Not real-time techniques: ``probes-reference`` recomputes 32x32-texel probes with 64 rays per texel every
frame (ADGI's reference; minutes per frame at its defaults), left out of ``--techniques all``."""
DEFAULT_SCENE = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "..", "shared", "scenes",
                             "cornell-box", "scene_mi3.xml")


def mitsuba_ms(scene, res, repeats=5):
    from dyngi.backend import dr, mi

    sensor = scene.camera(0.0).to_sensor(res, 1)
    integ = mi.load_dict({"type": "path", "max_depth": 12, "rr_depth": 5})
    ts = []
    for i in range(repeats + 1):
        t0 = time.perf_counter()
        img = mi.render(scene.mi_scene, sensor=sensor, integrator=integ, spp=1, seed=i)
        dr.eval(img)
        dr.sync_thread()
        ts.append(1e3 * (time.perf_counter() - t0))
    return float(np.median(ts[1:]))


def technique_ms(scene, spec_text, res, frames, skip, stages=None):
    """Median steady frame time (ms); with ``stages`` (a dict) also fills ``{stage: (median ms, median rays
    per pixel)}`` from the frames' stage timers (``FrameResult.stats``)."""
    from dyngi.backend import dr
    from dyngi.techniques.base import Frame, create_technique, parse_spec

    spec = parse_spec(spec_text)
    tech = create_technique(spec.name, scene, spec.params)
    scene.at(0.0)
    ts, st = [], []
    for i in range(frames):
        t0 = time.perf_counter()
        r = tech.step(Frame(i, 0.0, scene.camera(0.0), res, seed=1, static=i > 0))
        dr.sync_thread()
        ts.append(1e3 * (time.perf_counter() - t0))
        st.append(r.stats or {})
    if stages is not None:
        npix = res[0] * res[1]
        names = [k for k in (st[-1].get("ms") or {})] + [k for k in (st[-1].get("rays") or {})
                                                        if k not in (st[-1].get("ms") or {})]
        for k in names:
            stages[k] = (float(np.median([d.get("ms", {}).get(k, 0.0) for d in st[skip:]])),
                         float(np.median([d.get("rays", {}).get(k, 0) for d in st[skip:]])) / npix)
    return float(np.median(ts[skip:]))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene_arg", nargs="?", metavar="scene", help="the scene (as --scene)")
    ap.add_argument("--scene", default=None,
                    help="built-in scene name or a Mitsuba XML / OBJ / PLY file (default: ../shared's Cornell box)")
    ap.add_argument("--techniques", default="path;restir-pt",
                    help="';'-separated technique specs, or 'all' (every registered real-time technique, defaults)")
    ap.add_argument("--res", default="320x180")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--skip", type=int, default=4)
    ap.add_argument("--stages", action="store_true",
                    help="after each technique's row, its stage table: median ms and rays per pixel per stage")
    args = ap.parse_args()
    from dyngi import backend
    backend.set_device("cpu")
    from dyngi.errors import DyngiError
    from dyngi.scene import load_scene
    from dyngi.techniques.base import technique_names

    if args.scene and args.scene_arg and args.scene != args.scene_arg:
        ap.error("give the scene once (--scene or the first argument)")
    scene_name = args.scene or args.scene_arg or os.path.normpath(DEFAULT_SCENE)
    if args.skip >= args.frames:
        ap.error(f"--skip ({args.skip}) must be below --frames ({args.frames})")
    res = tuple(int(x) for x in args.res.split("x"))
    specs = ([n for n in technique_names() if n not in OFFLINE] if args.techniques.strip() == "all"
             else [s for s in args.techniques.split(";") if s])
    scene = load_scene(scene_name)
    scene.at(0.0)
    print(f"load {os.getloadavg()[0]:.1f}; {scene_name} at {res[0]}x{res[1]}; median of frames "
          f"{args.skip + 1}-{args.frames}")
    print("| technique | steady frame ms | Mitsuba path 1 spp ms | ratio |")
    print("|---|---|---|---|")
    for spec in specs:
        m0 = mitsuba_ms(scene, res)
        stages = {} if args.stages else None
        try:
            ms = technique_ms(scene, spec, res, args.frames, args.skip, stages)
        except Exception as e:      # one technique's failure is a row, not the end of the run
            if not isinstance(e, DyngiError):
                traceback.print_exc()
            print(f"| {spec} | failed: {type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''} | | |",
                  flush=True)
            continue
        m1 = mitsuba_ms(scene, res)
        ref = float(np.median([m0, m1]))
        print(f"| {spec} | {ms:.1f} | {ref:.1f} | {ms / ref:.2f} |", flush=True)
        if stages:
            print("|  stage | ms | rays per pixel | |")
            for k, (sms, rpp) in stages.items():
                print(f"|  {spec}: {k} | {sms:.1f} | {rpp:.2f} | |", flush=True)
    print(f"load {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
