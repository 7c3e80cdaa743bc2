import sys, time, numpy as np
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
sc = load_scene(sys.argv[1]); res = (640, 360)
for spec in sys.argv[2:]:
    tech = create_technique(spec, sc, {})
    ms = []
    for i in range(6):
        t = sc.frame_time(0); sc.at(t)
        f = Frame(index=i, time=t, camera=sc.camera(t), res=res, seed=0, static=i > 0)
        t0 = time.perf_counter(); r = tech.step(f); ms.append(1e3 * (time.perf_counter() - t0))
    print(spec, [round(x) for x in ms], "median(2..)", round(float(np.median(ms[2:]))), {k: round(v) for k, v in r.stats["ms"].items()}, flush=True)
