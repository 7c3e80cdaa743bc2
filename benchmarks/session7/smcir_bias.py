"""Bias ratios of smcir (mean indirect / clamped reference), exhaustive shading."""
import sys, time, json
import numpy as np
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
from dyngi.experiments.clamped_reference import clamped_indirect
from dyngi.vpl.shading import clamp_value

def run(scene, res, warmup, variants, ref_spp=1024, frame=0, seeds=(0,)):
    sc = load_scene(scene)
    t = sc.frame_time(frame)
    ref = clamped_indirect(sc, t, res, ref_spp, 5, clamp_value(sc, 0.05))
    out = {}
    for name, extra in variants:
        rs = []
        for seed in seeds:
            tech = create_technique("smcir", sc, {"warmup": warmup, "shading": "exhaustive", **extra})
            sc.at(t)
            ind = tech.step(Frame(frame, t, sc.camera(t), res, seed=seed)).indirect
            rs.append(ind.mean() / ref.mean())
        out[name] = (float(np.mean(rs)), float(np.std(rs)))
        print(scene, res, warmup, name, out[name], flush=True)
    for tn in ("mir", "ir"):
        tech = create_technique(tn, sc, {"shading": "exhaustive"})
        sc.at(t)
        ind = tech.step(Frame(frame, t, sc.camera(t), res, seed=0)).indirect
        print(scene, tn, ind.mean() / ref.mean(), flush=True)
    return out

V = [("same-seed (before)", {"reestimate": "same-seed"}),
     ("independent (after)", {}),
     ("independent, density_k=16", {"density_k": 16}),
     ("independent, spp=256", {"radiosity_spp": 256}),
     ("no replacements", {"warmup": 0, "max_moves": 0})]
which = sys.argv[1]
if which == "cornell":
    run("cornell-static", (48, 36), 100, V, seeds=(0, 1, 2))
elif which == "corridor":
    run("corridor-walk", (48, 27), 30, V, seeds=(0, 1, 2))
