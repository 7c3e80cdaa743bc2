import sys, time, numpy as np
from dyngi import backend as b
b.set_device("cpu")
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
from dyngi.metrics.image import mape
from dyngi.experiments.reference import reference_image, scene_max_depth
name = sys.argv[1]; res = (int(sys.argv[2]), int(sys.argv[3])); F = 8
sc = load_scene(name); sc.at(0.0)
ref = reference_image(sc, 0.0, res, 1024, scene_max_depth(sc))
import os
configs = [("no CV", {}), ("CV constant", {"control_variate": True}),
                 ("CV nearest-ray", {"control_variate": True, "cv_kind": "nearest-ray"})]
for label, p in [c for c in configs if os.environ.get("ONLY", "") in c[0]]:
    m1, m8, ms, neg = [], [], [], []
    for seed in range(3):
        t = create_technique("ddgi-resampling", sc, {**p, "progressive": False})
        acc = 0.0
        for i in range(F):
            t0 = time.perf_counter()
            r = t.step(Frame(i, 0.0, sc.camera(0.0), res, seed=seed, static=i > 0))
            dt = time.perf_counter() - t0
            acc = acc + r.image
            if i >= 2:
                ms.append(dt * 1e3); m1.append(mape(r.image, ref)); neg.append(float((r.image.min(2) < 0).mean()))
        m8.append(mape(acc / F, ref))
    print(f"| {name} {res[0]}x{res[1]} | {label} | {np.mean(m1):.3f} +- {np.std(m1):.3f} | {np.mean(m8):.3f} +- {np.std(m8):.3f} | {np.median(ms):.0f} | {np.mean(neg)*100:.2f} % |", flush=True)
