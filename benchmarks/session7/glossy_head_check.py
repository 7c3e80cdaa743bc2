import importlib.util, sys, numpy as np
from dyngi import backend as b
b.set_device("cpu")
import dyngi.probes.primary as new
src = open("/tmp/glossy_old_primary.py").read()
mod = type(sys)("dyngi.probes._old_primary"); mod.__package__ = "dyngi.probes"
exec(compile(src, "old_primary", "exec"), mod.__dict__)
from dyngi.scene import load_scene
from dyngi.techniques import create_technique, Frame
import dyngi.techniques.ddgi as D
for scene in ("glossy-floor", "room-metal-furniture", "light-behind-glass"):
    imgs = []
    old = lambda *a, glossy=False, **k: mod.shade_primary(*a, **k)
    for fn in (old, new.shade_primary):
        D.shade_primary = fn
        sc = load_scene(scene)
        t = create_technique("ddgi", sc, {"probe_counts": "3", "rays_per_probe": 32, "warmup": 2})
        out = []
        for i in range(3):
            ti = sc.frame_time(i); sc.at(ti)
            r = t.step(Frame(i, ti, sc.camera(ti), (32, 24), seed=5, static=False))
            out.append((np.asarray(r.image), np.asarray(r.indirect)))
        imgs.append(out)
    print(scene, "HEAD vs new glossy=False bit-identical:", all(np.array_equal(a[0], c[0]) and np.array_equal(a[1], c[1]) for a, c in zip(*imgs)))
