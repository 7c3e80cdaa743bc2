"""Steady frame time of techniques against Mitsuba's ``path`` at 1 spp, measured in the same run.

For each technique spec: ``--frames`` frames of the scene (static camera, so techniques with temporal
state reach their steady state), the median wall time of the frames after the first ``--skip`` (kernel
compilation, probe warm-up); Mitsuba's ``path`` integrator (``max_depth`` 12, 1 spp, same resolution)
is timed right before and after each technique and its median is the denominator, so a change of the
machine's load between techniques shows in the reference too. Prints one Markdown row per technique
and the machine load (``os.getloadavg``).

    .venv/bin/python benchmarks/frame_time.py ../shared/scenes/cornell-box/scene_mi3.xml \\
        --techniques "path;restir-pt" --res 320x180
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np


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


def technique_ms(scene, spec_text, res, frames, skip):
    from dyngi.backend import dr
    from dyngi.techniques.base import Frame, create_technique, parse_spec

    spec = parse_spec(spec_text)
    tech = create_technique(spec.name, scene, spec.params)
    scene.at(0.0)
    ts = []
    for i in range(frames):
        t0 = time.perf_counter()
        tech.step(Frame(i, 0.0, scene.camera(0.0), res, seed=1, static=i > 0))
        dr.sync_thread()
        ts.append(1e3 * (time.perf_counter() - t0))
    return float(np.median(ts[skip:]))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene", help="built-in scene name or a Mitsuba XML / OBJ / PLY file")
    ap.add_argument("--techniques", default="path;restir-pt", help="';'-separated technique specs")
    ap.add_argument("--res", default="320x180")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--skip", type=int, default=4)
    args = ap.parse_args()
    from dyngi import backend
    backend.set_device("cpu")
    from dyngi.scene import load_scene

    res = tuple(int(x) for x in args.res.split("x"))
    scene = load_scene(args.scene)
    scene.at(0.0)
    print(f"load {os.getloadavg()[0]:.1f}; {args.scene} at {res[0]}x{res[1]}")
    print("| technique | steady frame ms | Mitsuba path 1 spp ms | ratio |")
    print("|---|---|---|---|")
    for spec in [s for s in args.techniques.split(";") if s]:
        m0 = mitsuba_ms(scene, res)
        ms = technique_ms(scene, spec, res, args.frames, args.skip)
        m1 = mitsuba_ms(scene, res)
        ref = float(np.median([m0, m1]))
        print(f"| {spec} | {ms:.1f} | {ref:.1f} | {ms / ref:.2f} |", flush=True)
    print(f"load {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
