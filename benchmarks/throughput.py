"""Path tracer throughput vs raw ray tracing, measured in one run.

For a built-in scene and a real scene (../shared/scenes, when present):
* raw Mitsuba ``ray_intersect`` rays/s on 2M incoherent rays;
* dyngi ``path`` rays/s (camera + bounce + shadow rays, counted in the kernel) at 320x240;
* Mitsuba's own ``path`` integrator wall time at the same resolution, spp and depth;
and the ratios. Usage: python benchmarks/throughput.py [--res 320x240] [--spp 4]

Recorded in ``docs/techniques/path.md`` ("Path tracer against raw ray tracing and Mitsuba's `path`"), beside
the command, resolution, seeds and machine load of each run.
"""
from __future__ import annotations

import argparse
import sys

from common import best_of, md_table, raw_rays_per_second, shared_scene
from dyngi.backend import device_info, dr, mi
from dyngi.scene import load_scene
from dyngi.techniques.path import render_paths


def bench(scene, res, spp, depth=12):
    scene.at(0.0)
    cam = scene.camera(0.0)
    raw = raw_rays_per_second(scene.mi_scene)
    rays = {}

    def ours():
        L, n = render_paths(scene, cam, res, spp, seed=1, frame_index=0, max_depth=depth, rr_depth=5)
        dr.eval(L, n)
        rays["n"] = int(n[0])

    t_ours = best_of(ours)
    sensor = cam.to_sensor(res, spp)
    integ = mi.load_dict({"type": "path", "max_depth": depth, "rr_depth": 5})

    def theirs():
        img = mi.render(scene.mi_scene, sensor=sensor, integrator=integ, spp=spp, seed=1)
        dr.eval(img)

    t_mi = best_of(theirs)
    ours_rps = rays["n"] / t_ours
    return {
        "scene": scene.name, "res": f"{res[0]}x{res[1]}", "spp": spp,
        "raw full Mrays/s": raw["full"] / 1e6, "raw prelim Mrays/s": raw["preliminary"] / 1e6,
        "path Mrays/s": ours_rps / 1e6, "path/raw": ours_rps / raw["full"],
        "path ms": 1e3 * t_ours, "mitsuba path ms": 1e3 * t_mi, "mitsuba/ours time": t_mi / t_ours,
    }


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", default="320x240")
    ap.add_argument("--spp", type=int, default=4)
    a = ap.parse_args(argv)
    res = tuple(int(x) for x in a.res.split("x"))
    rows = [bench(load_scene("cornell-static"), res, a.spp)]
    for rel in ("staircase2/scene.xml", "veach-ajar/scene_nopots.xml"):
        p = shared_scene(rel)
        if p:
            rows.append(bench(load_scene(p), res, a.spp))
    print(f"device: {device_info()}")
    print(md_table(rows))
    return rows


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
