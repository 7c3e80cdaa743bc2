import numpy as np, time, cProfile, pstats
from dyngi.backend import mi, dr
from dyngi.sampling.octree import AdaptiveOctree
o = AdaptiveOctree([0,0,0],[40,6,20], 512, 256)
rng = np.random.default_rng(1)
P = rng.random((43000,3)) * [20,0.01,10]
p = mi.Point3f(*[mi.Float(P[:,k].astype(np.float32)) for k in range(3)])
for f in range(8):
    o.place(p); o.adapt()
print(o.stats())
ms=[]
def run():
    for f in range(40):
        o.place(p); dr.eval(o.counts); o.adapt(); ms.append(o.adapt_ms)
cProfile.run("run()", "/tmp/oct.prof")
print(np.median(ms), np.max(ms), np.percentile(ms, 90))
pstats.Stats("/tmp/oct.prof").sort_stats("tottime").print_stats(12)
