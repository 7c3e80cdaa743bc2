import sys, numpy as np
sys.path.insert(0, "tests")
from stats import z_test_images
from dyngi.backend import mi, dr
from dyngi.scene.library import make_builtin
from dyngi.techniques.base import create_technique, Frame
import dyngi.techniques._all  # noqa
sc = make_builtin("warehouse-lights")
t = 0.0; sc.at(t)
out = {}
for lights in ["uniform", "lighttree", "sll"]:
    imgs = []
    tech = create_technique("nee-pt", sc, {"lights": lights, "spp": 32})
    for k in range(10):
        r = tech.step(Frame(index=k, time=t, camera=sc.camera(t), res=(40, 24), seed=k))
        imgs.append(r.image)
    out[lights] = np.stack(imgs)
    print(lights, out[lights].mean(), out[lights].var(0).mean())
for k in ["lighttree", "sll"]:
    print(k, z_test_images(out[k], out["uniform"]))
