import numpy as np, time
from dyngi.backend import mi, dr
from dyngi.sampling.octree import AdaptiveOctree
o = AdaptiveOctree([0,0,0],[40,6,20], 512, 256)
rng = np.random.default_rng(1)
P = rng.random((43000,3)) * [20,0.01,10]
p = mi.Point3f(*[mi.Float(P[:,k].astype(np.float32)) for k in range(3)])
for f in range(8):
    o.place(p); o.adapt()
n = 1_000_000
Q = rng.random((n,3)) * [20,0.01,10]
q = mi.Point3f(*[mi.Float(Q[:,k].astype(np.float32)) for k in range(3)])
dr.eval(q)
for name, fn in [("lookup", lambda: o.lookup(q)), ("lookup_pair", lambda: o.lookup_pair(q, q)[1]), ("place", lambda: (o.place(q), o.counts)[1])]:
    ts = []
    for i in range(7):
        t0 = time.perf_counter(); r = fn(); dr.eval(r); dr.sync_thread(); ts.append(time.perf_counter() - t0)
    print(name, "leaves", o.leaf_count, "depth", o.stats()["max_depth"], "median ms per 1M points", round(1e3 * np.median(ts[2:]), 2))
