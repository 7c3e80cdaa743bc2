"""Where a steady frame of the SMC-IR reproduction's techniques spends its time.

For each technique spec: ``--frames`` frames of the sequence at ``--res`` (the sequence's own camera
path, frame ``i`` at ``scene.frame_time(i)``, seed 0, as ``dyngi reproduce smcir`` runs them); prints per
frame the wall time and the technique's own stage milliseconds, and for the last frame the Dr.Jit
kernels launched (count, launches with their execution time when Dr.Jit records it). Machine load
(``os.getloadavg``) before and after.

    nice .venv/bin/python benchmarks/smcir_profile.py corridor-walk --techniques mir --res 160x90 --frames 4

Recorded in ``docs/vpl.md`` ("Where the SMC-IR reproduction spends its time"), beside the command, resolution,
seeds and machine load of each run.
"""
from __future__ import annotations

import argparse
import json
import os
import time


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene")
    ap.add_argument("--techniques", default="mir")
    ap.add_argument("--res", default="160x90")
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--kernels", action="store_true", help="kernel history of the last frame")
    args = ap.parse_args()
    from dyngi import backend
    backend.set_device("cpu")
    from dyngi.backend import dr
    from dyngi.scene import load_scene
    from dyngi.techniques.base import Frame, create_technique, parse_spec

    res = tuple(int(v) for v in args.res.split("x"))
    scene = load_scene(args.scene)
    print("load before", os.getloadavg())
    for text in args.techniques.split(";"):
        spec = parse_spec(text)
        tech = create_technique(spec.name, scene, spec.params)
        for i in range(args.frames):
            t = scene.frame_time(i)
            scene.at(t)
            last = i == args.frames - 1
            if last and args.kernels:
                dr.kernel_history_clear()
                dr.set_flag(dr.JitFlag.KernelHistory, True)
            t0 = time.perf_counter()
            r = tech.step(Frame(i, t, scene.camera(t), res, seed=0))
            dr.sync_thread()
            wall = time.perf_counter() - t0
            ms = {k: round(v, 1) for k, v in r.stats.get("ms", {}).items()}
            print(f"{text} frame {i}: {wall:.2f} s  stages {json.dumps(ms)}", flush=True)
            if last and args.kernels:
                hist = dr.kernel_history()
                dr.set_flag(dr.JitFlag.KernelHistory, False)
                ks = [h for h in hist if h.get("type") == dr.KernelType.JIT]
                print(f"  kernels launched: {len(ks)}, their execution {sum(h.get('execution_time', 0) for h in ks):.1f} ms "
                      f"of the frame's {1e3 * wall:.1f} ms (the rest: tracing, compilation, host work)")
                for h in sorted(ks, key=lambda h: -h.get("execution_time", 0))[:12]:
                    print(f"   {h.get('execution_time', 0):9.1f} ms  size {h.get('size')}  ops {h.get('operation_count')}"
                          f"  cache_hit {h.get('cache_hit')}")
    print("load after", os.getloadavg())


if __name__ == "__main__":
    main()
