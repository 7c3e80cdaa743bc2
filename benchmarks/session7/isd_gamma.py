import numpy as np, sys
import dyngi.backend
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
scene = load_scene("cornell-moving-box")
t = scene.frame_time(0); scene.at(t)
res = (32, 24)
specs = ["ddgi:probe_counts=4", "isddgi:probe_counts=4", "isddgi:probe_counts=4:x_min=16", "isddgi:probe_counts=4:irradiance_gamma=1", "ddgi:probe_counts=4:irradiance_gamma=1"]
out = {}
for spec in specs:
    tech = create_technique(spec, scene)
    acc = 0
    for i in range(40):
        r = tech.step(Frame(i, t, scene.camera(t), res, seed=0))
        if i >= 16:
            acc = acc + r.indirect
    out[spec] = acc / 24
    print(spec, "mean indirect %.5f" % out[spec].mean(), "ratio vs ddgi-256 g5 %.3f" % (out[spec].mean() / out[specs[0]].mean()),
          "vs ddgi-256 g1 %.3f" % (out[spec].mean() / out[specs[4]].mean() if specs[4] in out else float('nan')), flush=True)
