import sys, time, numpy as np
from dyngi.backend import dr, mi
from dyngi.scene.library import make_builtin
from dyngi.techniques.base import Frame, create_technique
from dyngi.scene.builtin import _sun_dir
sc = make_builtin("sky-pit-sun-disc")
for spec in sys.argv[2:]:
    tech = create_technique(spec, sc)
    t0 = time.time()
    for i in range(int(sys.argv[1])):
        f = Frame(index=i, time=0.0, camera=sc.camera(0.0), res=(160, 90), seed=0, ray_budget=None, static=i > 0)
        r = tech.step(f)
        if i % 20 == 19 or i == int(sys.argv[1]) - 1:
            g = tech.cdq; n = g._rows
            d = -_sun_dir(70, 200)
            leaf = mi.UInt32(np.arange(n, dtype=np.uint32))
            p = g.pdf(leaf, mi.Vector3f(*[mi.Float(np.full(n, float(v))) for v in d]), True).numpy()
            print(spec, i, f"{time.time()-t0:.0f}s leaves {n} pdf(sun)*4pi: median {np.median(p)*4*np.pi:.3g} p90 {np.percentile(p,90)*4*np.pi:.3g} max {p.max()*4*np.pi:.3g}", r.stats.get("cdq"))
