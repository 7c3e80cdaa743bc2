import time, collections
import numpy as np
from dyngi.backend import dr, mi
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
import dyngi.techniques.adgi.technique as T
acc = collections.defaultdict(float)
def wrap(obj, name, label):
    f = getattr(obj, name)
    def g(*a, **k):
        dr.sync_thread(); w = time.perf_counter(); r = f(*a, **k)
        if hasattr(r, "radiance"): dr.eval(r.radiance, r.distance)
        elif isinstance(r, mi.Float): dr.eval(r)
        dr.sync_thread()
        acc[label] += 1e3 * (time.perf_counter() - w); return r
    setattr(obj, name, g)
sc = load_scene("tunnel-gate")
a = create_technique("adgi", sc, {})
wrap(T, "trace_probe_rays", "trace_probe_rays")
wrap(T, "trace_probe_distances", "trace_probe_distances")
wrap(T, "frusta", "frusta")
wrap(T, "pack_heuristics", "pack")
wrap(T, "sorted_plan", "sorted_plan")
wrap(a.heur, "update", "heur.update")
wrap(a.heur.pilot, "plan", "pilot.plan")
wrap(a, "_merge", "_merge")
wrap(a.radiance, "merge", "merge.radiance")
wrap(a.est_dist, "distance", "merge.est_dist")
wrap(T, "merge_into_volume", "merge_into_volume")
wrap(a, "_convolve_updated", "convolve_updated")
wrap(a, "_cap_outer", "cap_outer")
wrap(a, "guide_feedback", "guide_feedback")
wrap(a.static, "run", "chains.run")
wrap(a.dynamic, "run", "chains.run")
wrap(a, "_primary", "primary")
N = 6
for f in range(3 + N):
    if f == 3: acc.clear(); w0 = time.perf_counter()
    t = 2.0 + f / 15; sc.at(t)
    r = a.step(Frame(f, t, sc.camera(t), (64, 48), seed=0, ray_budget=39644 if f else None))
tot = 1e3 * (time.perf_counter() - w0) / N
print("frame ms %.1f" % tot, {k: round(v / N, 1) for k, v in sorted(acc.items(), key=lambda x: -x[1])})
