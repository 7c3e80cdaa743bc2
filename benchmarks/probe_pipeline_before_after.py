"""Does the probe pipeline render what the per-technique loops rendered? Snapshot, then compare (issue 23, item 1).

Every probe technique of the DDGI family (``ddgi``, ``qddgi``, ``probes-reference``, ``adgi``, ``isddgi``)
renders a few frames of one small dynamic scene at fixed seeds, and the DDGI+ volume
(:class:`dyngi.probes.ddgi_plus.DDGIPlusVolume`) runs a few updates; the images, indirect images and the
DDGI+ volume's atlases are stored. Run ``snapshot`` on the tree before the change
(``PYTHONPATH=/path/to/old/src``) and after, then ``compare``: per entry bit-identical, or the largest
difference and a per-pixel z-test over ``--seeds`` independent renders
(:func:`benchmarks.before_after.compare`).

    .venv/bin/python benchmarks/probe_pipeline_before_after.py snapshot /tmp/before.npz
    .venv/bin/python benchmarks/probe_pipeline_before_after.py compare /tmp/before.npz /tmp/after.npz
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

SCENE = "cornell-moving-box"
TECHNIQUES = ("ddgi:probe_counts=4:rays_per_probe=32:warmup=2",
              "qddgi:probe_counts=4:warmup=2:update_offscreen=true",
              "probes-reference:probe_counts=3:texels=8:rays_per_texel=4",
              "adgi:probe_counts=4:static_chains=256:dynamic_chains=64:warmup=2:warmup_rays=32:reclassify_interval=2",
              "isddgi:probe_counts=4:warmup=1:reclassify_interval=2")
PLUS = {"probe_counts": "4", "rays_per_probe": 32, "warmup": 2}


def snapshot(out, res, frames, seeds, techniques, scene):
    from dyngi import backend
    backend.set_device("cpu")
    from dyngi.experiments.runner import run_sequence
    from dyngi.scene import load_scene
    from dyngi.techniques.base import create_technique, parse_spec

    data = {}
    for spec_text in techniques:
        spec = parse_spec(spec_text)
        for s in range(seeds):
            sc = load_scene(scene)
            tech = create_technique(spec.name, sc, spec.params)
            r = run_sequence(sc, tech, frames, res, seed=s)
            for i, img in enumerate(r.images):
                data[f"{scene}|{spec_text}|{s}|{i}|image"] = img
                if r.indirect[i] is not None:
                    data[f"{scene}|{spec_text}|{s}|{i}|indirect"] = r.indirect[i]
        print(spec_text, flush=True)
    # the DDGI+ volume (probes/ddgi_plus.py): its atlases after each update
    from dyngi.probes.ddgi_plus import DDGIPlusVolume
    from dyngi.techniques.base import Frame
    for s in range(seeds):
        sc = load_scene(scene)
        vol = DDGIPlusVolume(sc, PLUS)
        for i in range(frames):
            t = i / 30.0
            sc.at(t)
            vol.update(Frame(i, t, sc.camera(t), res, seed=s * 1000 + i))
            st = vol.volume.state
            data[f"{scene}|ddgi-plus-volume|{s}|{i}|irradiance"] = np.asarray(st.irradiance).copy()
            data[f"{scene}|ddgi-plus-volume|{s}|{i}|distance"] = np.asarray(st.distance).copy()
    print("ddgi-plus-volume", flush=True)
    np.savez_compressed(out, **data)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("snapshot")
    s.add_argument("out")
    s.add_argument("--res", default="32x18")
    s.add_argument("--frames", type=int, default=4)
    s.add_argument("--seeds", type=int, default=1)
    s.add_argument("--techniques", default=";".join(TECHNIQUES), help="';'-separated specs")
    s.add_argument("--scene", default=SCENE)
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    args = ap.parse_args()
    if args.cmd == "snapshot":
        w, h = (int(x) for x in args.res.split("x"))
        snapshot(args.out, (w, h), args.frames, args.seeds, [t for t in args.techniques.split(";") if t],
                 args.scene)
        return 0
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from before_after import compare
    return compare(args.a, args.b)


if __name__ == "__main__":
    sys.exit(main())
