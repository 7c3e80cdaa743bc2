import numpy as np, time, sys, importlib.util
import dyngi.backend
from dyngi.backend import dr, mi
from dyngi.probes.isddgi_planner import ISDDGIPlanner
from dyngi.probes import isddgi_estimator as NEW
spec = importlib.util.spec_from_file_location("isd_est_before", "/tmp/isd_before/isddgi_estimator_before.py")
OLD = importlib.util.module_from_spec(spec); sys.modules[spec.name] = OLD; spec.loader.exec_module(OLD)
P = 2048
pl = ISDDGIPlanner(P)
plan = pl.plan(3, 1, np.arange(P, dtype=np.uint32))
R = plan.n_rays
rng = np.random.default_rng(0)
L = mi.Color3f(*[mi.Float(rng.random(R).astype(np.float32)) for _ in range(3)])
d = mi.Float((rng.random(R) + 0.2).astype(np.float32)); dr.eval(L, d)
tm = {"before": [], "after": []}
for it in range(6):
    for name, M in (("before", OLD), ("after", NEW)):
        t0 = time.perf_counter()
        ei, ed = M.integrate_sets_dr(plan, L, d, 2.0, 50.0)
        dr.sync_thread()
        if it >= 2: tm[name].append(1e3 * (time.perf_counter() - t0))
        if it == 0:
            v = np.asarray(ei.value); vd = np.asarray(ed.value)
            if name == "before": ref = (v, vd)
            else: print("max diff", np.abs(v - ref[0]).max(), np.abs(vd - ref[1]).max())
print({k: "%.1f ms (median of %d)" % (np.median(v), len(v)) for k, v in tm.items()}, "rays", R, "probes", P)
