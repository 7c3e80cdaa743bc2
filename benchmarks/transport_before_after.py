"""Do the techniques moved onto the one path walk render what they rendered before? (issue 24, item 1)

The glossy recursions of the DDGI Resampling family (``ddgi-primary``'s ``T_fg L``, the footprint-terminated
recursion of ``S(x_n)`` in ``ddgi-secondary`` / ``ddgi-resampling``) and ``nee-pt`` were each a loop of their
own; they now call :func:`dyngi.transport.path_walk.walk` with per-vertex hooks. The walk draws its random
numbers in its own order (and one Russian-roulette number per bounce), so the renders are not bit-identical:
each technique renders ``--seeds`` independent sequences on three scenes before and after the change, and
:func:`before_after.compare` runs a per-pixel two-sample z-test of the last frame (Sidak-corrected over the
pixel-channels, alpha 0.01) per technique, scene and image (full, indirect).

    git archive <before> src | tar -x -C /tmp/before     # the tree before the change
    PYTHONPATH=/tmp/before/src nice .venv/bin/python benchmarks/transport_before_after.py snapshot /tmp/a.npz
    nice .venv/bin/python benchmarks/transport_before_after.py snapshot /tmp/b.npz
    .venv/bin/python benchmarks/transport_before_after.py compare /tmp/a.npz /tmp/b.npz
"""
from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from before_after import compare  # noqa: E402

SCENES = ("cornell-static", "glossy-floor", "light-behind-glass")
TECHNIQUES = ("ddgi-primary:candidates=4:probe_counts=3:rays_per_probe=16:warmup=1",
              "ddgi-secondary:candidates=4:probe_counts=3:rays_per_probe=16:warmup=1:progressive=false",
              "ddgi-resampling:candidates=4:probe_counts=3:rays_per_probe=16:warmup=1:progressive=false",
              "nee-pt:lights=power")


def snapshot(out, res, frames, seeds, techniques, scenes):
    """Render every technique spec on every scene for ``frames`` frames and ``seeds`` seeds; store the images."""
    import numpy as np

    from dyngi import backend
    backend.set_device("cpu")
    from dyngi.experiments.runner import run_sequence
    from dyngi.scene import load_scene
    from dyngi.techniques.base import create_technique, parse_spec

    data = {}
    for sc_name in scenes:
        for spec_text in techniques:
            spec = parse_spec(spec_text)
            for s in range(seeds):
                sc = load_scene(sc_name)
                tech = create_technique(spec.name, sc, spec.params)
                r = run_sequence(sc, tech, frames, res, seed=s)
                for i, img in enumerate(r.images):
                    data[f"{sc_name}|{spec_text}|{s}|{i}|image"] = img
                    if r.indirect[i] is not None:
                        data[f"{sc_name}|{spec_text}|{s}|{i}|indirect"] = r.indirect[i]
            print(sc_name, spec_text, flush=True)
    np.savez_compressed(out, **data)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("snapshot")
    s.add_argument("out")
    s.add_argument("--res", default="32x18")
    s.add_argument("--frames", type=int, default=2)
    s.add_argument("--seeds", type=int, default=12)
    s.add_argument("--techniques", default=";".join(TECHNIQUES), help="';'-separated specs")
    s.add_argument("--scenes", default=",".join(SCENES))
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    args = ap.parse_args()
    if args.cmd == "snapshot":
        w, h = (int(x) for x in args.res.split("x"))
        snapshot(args.out, (w, h), args.frames, args.seeds, [t for t in args.techniques.split(";") if t],
                 args.scenes.split(","))
        return 0
    return compare(args.a, args.b)


if __name__ == "__main__":
    sys.exit(main())
