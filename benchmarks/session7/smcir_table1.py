"""Reduced Table 1 run: the module's run_scene/_rows with a smaller config (the full one does not fit)."""
import json, os, sys
from dyngi.experiments.reproductions import smcir as R

CFG = {"scenes": tuple(sys.argv[2].split(",")), "res": (48, 27), "frames": 12, "ref_spp": 128,
       "specs": ("mir:resampling_rate=64", "ir", "tcas", "smcir:warmup=30", "smcir:warmup=30:density_k=16")}
out = sys.argv[1]
figs = {}
for sc in CFG["scenes"]:
    figs[sc] = R.run_scene(sc, CFG, os.path.join(out, sc), True)
    json.dump(figs, open(os.path.join(out, "figs.json"), "w"), indent=1, default=float)
    print("done", sc, flush=True)
