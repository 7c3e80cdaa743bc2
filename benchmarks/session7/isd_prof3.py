import numpy as np, time, sys, importlib.util
import dyngi.backend
from dyngi.backend import dr, mi
import dyngi.probes.isddgi_planner as M
def load(path):
    spec = importlib.util.spec_from_file_location("dyngi.probes._isd_before", path)
    m = importlib.util.module_from_spec(spec); sys.modules[spec.name] = m; spec.loader.exec_module(m); return m
mods = {"before": load("/tmp/isd_before/isddgi_planner_before.py"), "after": M}
P = 2048
rng = np.random.default_rng(0)
for name, mod in mods.items():
    pl = mod.ISDDGIPlanner(P, x_init=32, importance_rays=16, max_distance=2.0)
    ids = np.arange(P, dtype=np.uint32)
    tp, to = [], []
    for t in range(24):
        if t == 10:
            pl.state.F[:200] = 1.0; pl.state.f[:200, :30] = 1.0
        t0 = time.perf_counter()
        plan = pl.plan(t, 0, ids)
        dr.eval(plan.direction, plan.weight); dr.sync_thread()
        t1 = time.perf_counter()
        R = plan.n_rays
        lum = rng.random(R); d = rng.random(R) + 0.5
        pl.observe(plan, lum, d)
        t2 = time.perf_counter()
        if t >= 12: tp.append(t1 - t0); to.append(t2 - t1)
    print(name, "plan %.1f ms  observe %.1f ms  rays %d" % (1e3*np.median(tp), 1e3*np.median(to), R))
import cProfile, pstats
pl = M.ISDDGIPlanner(P, x_init=32, importance_rays=16, max_distance=2.0)
pl.state.F[:200] = 1.0; pl.state.f[:200, :30] = 1.0
pr = cProfile.Profile(); pr.enable()
for t in range(5):
    plan = pl.plan(t, 0, ids); dr.eval(plan.direction, plan.weight); dr.sync_thread()
pr.disable(); pstats.Stats(pr).sort_stats("tottime").print_stats(15)
