import sys, time, numpy as np
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
sc = load_scene(sys.argv[1]); res = (640, 360)
for name in sys.argv[2:]:
    tech = create_technique(name, sc, {})
    ms = []; st = None
    for i in range(5):
        t = sc.frame_time(0); sc.at(t)
        f = Frame(index=i, time=t, camera=sc.camera(t), res=res, seed=0, static=i > 0)
        t0 = time.perf_counter(); r = tech.step(f); ms.append(1e3 * (time.perf_counter() - t0)); st = r.stats
    print(name, "frame ms", [round(x) for x in ms], "median(2..)", round(float(np.median(ms[2:]))), "table2", st.get("table2_ms"),
          {k: round(v) for k, v in st["ms"].items()}, flush=True)
