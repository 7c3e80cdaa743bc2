import numpy as np, time, json, sys
from dyngi.backend import mi, dr
from dyngi.scene.library import make_builtin
from dyngi.techniques.base import create_technique
from dyngi.experiments.runner import run_sequence
import dyngi.techniques._all  # noqa
res = (160, 90)
sc = make_builtin("warehouse-lights")
tech = create_technique("nee-pt", sc, {"lights": "vlc"})
rows = []
def on_frame(i, frame, r):
    o = r.stats.get("octree", {})
    rows.append((i, o.get("leaves"), o.get("splits"), o.get("collapses"), o.get("adapt_ms"), o.get("count_sync_ms"), o.get("max_depth"), o.get("placed"), r.stats["ms"].get("adapt"), r.stats["ms"].get("trace")))
run_sequence(sc, tech, 30, res, on_frame=on_frame, keep_images=False)
print("split/collapse thresholds", tech.octree.split_threshold, tech.octree.collapse_threshold)
print("frame leaves splits collapses adapt_ms(octree) count_sync_ms max_depth placed stage_adapt_ms trace_ms")
for r in rows: print(*[round(x, 2) if isinstance(x, float) else x for x in r])
