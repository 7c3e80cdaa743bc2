import time, sys
import numpy as np
from dyngi.backend import dr, mi
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
sc = load_scene("tunnel-gate")
res=(32,24)
budget = int(sys.argv[1]) if len(sys.argv)>1 and sys.argv[1]!="0" else None
name = sys.argv[2] if len(sys.argv)>2 else "adgi"
tech = create_technique(name, sc, {})
def fr(f):
    t=0.5+0.1*f; sc.at(t); return Frame(f,t,sc.camera(t),res,seed=0, ray_budget=budget if f else None)
for f in range(3): tech.step(fr(f))
dr.set_flag(dr.JitFlag.KernelHistory, True)
dr.kernel_history()
w=time.perf_counter()
N=4
for f in range(3,3+N): r=tech.step(fr(f))
wall=(time.perf_counter()-w)/N*1e3
h=dr.kernel_history()
jit=[k for k in h if k["type"]==dr.KernelType.JIT]
ex=sum(k.get("execution_time",0) for k in jit)/N
print(name, "budget",budget,"wall ms/frame %.1f"%wall, "kernel exec ms/frame %.1f"%ex, "kernels/frame", len(jit)/N, "launches all types", len(h)/N)
big=sorted(jit,key=lambda k:-k.get("execution_time",0))[:8]
for k in big: print("  %.2f ms size %d ops %s"%(k["execution_time"], k["size"], k.get("operation_count")))
print(r.stats["ms"], r.stats["total_rays"])
