import numpy as np
from dyngi.backend import mi
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
import sys
sc = load_scene(sys.argv[1]); cam = sc.camera(0.0); res = (64, 36)
ref = np.asarray(mi.render(sc.mi_scene, sensor=cam.to_sensor(res, 512), integrator=mi.load_dict({"type": "path", "max_depth": 12}), spp=512), np.float64)
lum = lambda x: x @ np.array([0.2126, 0.7152, 0.0722])
for spec in sys.argv[2].split(","):
    tech = create_technique(spec, sc, {})
    imgs = np.array([tech.step(Frame(i, 0.0, cam, res, seed=0, static=i > 0)).image for i in range(12)])
    m = imgs[4:].mean(0)
    one = imgs[-1]
    rel1 = ((lum(one) - lum(ref))**2 / (lum(ref)**2 + 1e-2)).mean()
    print(f"{spec}: mean {lum(m).mean():.4f} ref {lum(ref).mean():.4f} ({lum(m).mean()/lum(ref).mean()-1:+.3f}); 1-frame relMSE {rel1:.3f}; max {lum(one).max():.2f}")
