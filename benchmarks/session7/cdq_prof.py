import time, sys, numpy as np
from dyngi.backend import dr, mi
from dyngi.scene.library import make_builtin
from dyngi.techniques.base import Frame, create_technique
sc = make_builtin(sys.argv[1])
res = (int(sys.argv[2]), int(sys.argv[3]))
for spec in sys.argv[4:]:
    params = dict(kv.split("=") for kv in spec.split(":")[1:])
    tech = create_technique("nee-pt", sc, params)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    seen = set()
    for i in range(8):
        sc.at(0.0)
        dr.kernel_history()
        f = Frame(index=i, time=0.0, camera=sc.camera(0.0), res=res, seed=0, ray_budget=None, static=i > 0)
        t0 = time.perf_counter(); r = tech.step(f); dt = 1e3 * (time.perf_counter() - t0)
        h = {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}
        new = h - seen; seen |= h
        print(spec, i, f"{dt:.0f} ms", "new kernels", len(new), {k: round(v, 1) for k, v in r.stats["ms"].items()}, r.stats.get("cdq", {}).get("cdq_migrations"), r.stats["octree"]["leaves"] if "octree" in r.stats else "")
