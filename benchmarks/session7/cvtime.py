import time, numpy as np
from dyngi import backend as b
b.set_device("cpu")
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
sc = load_scene("cornell-static"); sc.at(0.0); res = (160, 90)
for label, p in [("no CV", {}), ("CV constant", {"control_variate": True}),
                 ("CV nearest-ray", {"control_variate": True, "cv_kind": "nearest-ray"})]:
    t = create_technique("ddgi-resampling", sc, p); ms = []
    for i in range(6):
        t0 = time.perf_counter(); t.step(Frame(i, 0.0, sc.camera(0.0), res, seed=0, static=i > 0))
        ms.append((time.perf_counter() - t0) * 1e3)
    print(f"| cornell-static 160x90 | {label} | {np.median(ms[2:]):.0f} ms |", flush=True)
