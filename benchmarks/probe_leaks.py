"""Probe leaks through thick two-sided geometry: probe techniques against Mitsuba's ``path``.

For each technique: the sealed room's image mean over the open room's (``sealed-rooms`` /
``sealed-rooms-open``; Mitsuba: 0), the ``stair-hall`` mean over Mitsuba's, and the mean over Mitsuba's on
the real scenes of ``../shared/scenes`` (those present). Each run renders ``--frames`` frames of the
static scene at ``--res`` and averages the second half; references are Mitsuba ``path`` at ``--ref-spp``
with the scene's own depth (cached, :mod:`dyngi.experiments.references.path`).

To measure the code before the two-sided rule, run this script from a ``git worktree`` of that commit with
``PYTHONPATH=<worktree>/src`` after copying ``src/dyngi/scene/builtin_probe_leaks.py`` into it (the analog
scenes are new). Example::

    .venv/bin/python benchmarks/probe_leaks.py --techniques ddgi --res 64x36 --frames 12

Recorded in ``docs/techniques/ddgi.md`` ("Probe leaks through thick two-sided geometry"), beside the command,
resolution, seeds and machine load of each run.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from common import shared_scene

REAL = ("cornell-box/scene_mi3.xml", "veach-ajar/scene_nopots.xml", "veach-bidir/scene_mi3.xml",
        "staircase2/scene.xml")


def mean_image(name: str, scene, res, frames: int, params: dict) -> np.ndarray:
    from dyngi.techniques import Frame, create_technique

    scene.at(0.0)
    tech = create_technique(name, scene, params)
    imgs = [tech.step(Frame(i, 0.0, scene.camera(0.0), res, seed=3, static=i > 0)).image for i in range(frames)]
    return np.mean(imgs[frames // 2:], 0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--techniques", default="ddgi", help="comma-separated technique specs (default ddgi)")
    ap.add_argument("--res", default="64x36")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--set", nargs="*", default=[], help="KEY=VALUE technique parameters for every technique")
    ap.add_argument("--no-real", action="store_true", help="skip the scenes of ../shared/scenes")
    a = ap.parse_args()

    from dyngi import backend
    backend.set_device("cpu")
    from dyngi.experiments.references.path import reference_image, scene_max_depth
    from dyngi.scene import load_scene

    res = tuple(int(v) for v in a.res.split("x"))
    params = dict(kv.split("=", 1) for kv in a.set)
    real = [] if a.no_real else [(r, shared_scene(r)) for r in REAL]
    real = [(r, p) for r, p in real if p is not None]
    head = ["technique", "sealed/open", "stair-hall"] + [r.split("/")[0] for r, _ in real]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    refs = {}

    def ratio(name, key, scene):
        if key not in refs:
            refs[key] = reference_image(scene, 0.0, res, a.ref_spp, scene_max_depth(scene)).mean()
        return mean_image(name, scene, res, a.frames, params).mean() / refs[key]

    for name in a.techniques.split(","):
        t0 = time.time()
        sealed = mean_image(name, load_scene("sealed-rooms"), res, a.frames, params).mean()
        lit = mean_image(name, load_scene("sealed-rooms-open"), res, a.frames, params).mean()
        row = [name, f"{sealed / lit:.4f}", f"{ratio(name, 'hall', load_scene('stair-hall')):.3f}"]
        for r, p in real:
            row.append(f"{ratio(name, r, load_scene(p)):.3f}")
        print("| " + " | ".join(row) + f" |   ({time.time() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
