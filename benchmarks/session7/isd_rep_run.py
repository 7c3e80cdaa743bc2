import json, os, sys, time
import dyngi.backend
from dyngi.experiments.reproductions import isddgi as R
cfg = {"scenes": R.SCENES, "res": (64, 48), "frames": 24, "ref_spp": 128, "scene_frames": {"corridor-rooms": 45}}
figs = []
for sc in cfg["scenes"]:
    t0 = time.time()
    f = R.run_scene(sc, cfg, os.path.join("/tmp/isd_rep/outC", sc), quiet=True)
    f["wall_s"] = time.time() - t0
    figs.append(f)
    print(json.dumps(f), flush=True)
    os.system("uptime")
with open("/tmp/isd_rep/figsC.json", "w") as fh:
    json.dump(figs, fh, indent=1)
for q, p, o in R._rows(figs):
    print(q, "|", p, "|", o)
