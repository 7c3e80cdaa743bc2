import time, numpy as np, sys
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
res = (int(sys.argv[1]), int(sys.argv[2]))
scenes = sys.argv[3].split(",")
specs = sys.argv[4].split(",")
for name in scenes:
    sc = load_scene(name)
    for spec in specs:
        tech = create_technique(spec, sc, {})
        ts = []; st = None
        for i in range(8):
            t0 = time.perf_counter()
            r = tech.step(Frame(i, 0.0, sc.camera(0.0), res, seed=0, static=False))
            ts.append(1e3*(time.perf_counter()-t0))
        st = r.stats
        print(f"{name} {spec} {res[0]}x{res[1]} frame ms median(frames 3-7) {np.median(ts[3:]):.1f}  stages " + " ".join(f"{k}={v:.1f}" for k, v in st['ms'].items()))
