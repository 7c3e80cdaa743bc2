import sys, json
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
sc = load_scene(sys.argv[1]); res = (640, 360)
tech = create_technique("smcir", sc, {"warmup": 2, **dict(kv.split("=") for kv in sys.argv[2:])})
for i in range(4):
    t = sc.frame_time(i); sc.at(t)
    r = tech.step(Frame(i, t, sc.camera(t), res, seed=0))
    ms = r.stats.get("ms", {})
    samp = sum(ms.get(k, 0.0) for k in ("candidates", "resampling", "visibility", "radiosity", "knn"))
    print(i, {k: round(v, 1) for k, v in ms.items()}, "sampling", round(samp, 1), "shading", round(ms.get("shading", 0), 1), flush=True)
