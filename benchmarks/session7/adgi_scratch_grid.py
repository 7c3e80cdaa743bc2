import time, sys, os
import numpy as np
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
sc = load_scene("tunnel-gate")
res=(32,24)
for counts in sys.argv[1:]:
    for name in ("qddgi","adgi"):
        p={"probe_counts":counts,"warmup":1}
        if name=="adgi": p["warmup_rays"]=32
        w0=time.perf_counter()
        tech=create_technique(name, sc, p)
        ms=[]
        for f in range(4):
            t=1.5+0.25*f; sc.at(t)
            w=time.perf_counter(); r=tech.step(Frame(f,t,sc.camera(t),res,seed=0)); ms.append(1e3*(time.perf_counter()-w))
        st=r.stats["ms"]
        samp = sum(st.get(k,0) for k in ("P","S","D")) if name=="adgi" else sum(st.get(k,0) for k in ("trace probes","shade probes","blend","states"))
        print(f"{counts} {name} probes={tech.volume.n_probes} frame0={ms[0]:.0f}ms steady={np.mean(ms[1:]):.0f}ms sampling={samp:.0f}ms rays={r.stats['total_rays']} stages={ {k:round(v) for k,v in st.items()} } setup+4frames={time.perf_counter()-w0:.0f}s load={os.getloadavg()[0]:.1f}", flush=True)
