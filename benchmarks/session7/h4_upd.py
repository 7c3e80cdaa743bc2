import time, numpy as np
from dyngi.scene import load_scene
from dyngi.techniques import Frame
from dyngi.probes.ddgi_plus import DDGIPlusVolume
for name in ["cornell-static", "glossy-floor", "living-room"]:
    sc = load_scene(name)
    for mode in ["ddgi", "plus"]:
        v = DDGIPlusVolume(sc, {}, mode=mode)
        ts = []
        for i in range(10):
            t0 = time.perf_counter()
            st = v.update(Frame(i, 0.0, sc.camera(0.0), (160, 90), seed=0))
            ts.append(1e3*(time.perf_counter()-t0))
        print(f"{name} mode={mode} probes={v.volume.n_probes} active={st['active_probes']} update ms median(frames 3-9) {np.median(ts[3:]):.1f} " + " ".join(f"{k}={x:.1f}" for k, x in st['ms'].items()))
