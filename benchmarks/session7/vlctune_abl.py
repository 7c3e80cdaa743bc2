"""vlctune ablation: per-frame MSE (+ firefly-excluded variants) of nee-pt variants vs a cached Mitsuba reference."""
import json, sys, time, os
import numpy as np
from dyngi.scene import load_scene
from dyngi.experiments.evaluate import _collect_images
from dyngi.experiments.runner import run_sequence
from dyngi.techniques import create_technique

scene_name, res, frames, ref_spp = sys.argv[1], tuple(int(x) for x in sys.argv[2].split("x")), int(sys.argv[3]), int(sys.argv[4])
specs = sys.argv[5:]
out = os.environ.get("ABL_OUT", "/tmp/vlctune/abl.jsonl")
sc = load_scene(scene_name)
t0 = time.time()
refs, noise = _collect_images(sc, frames, res, ref_spp, 3)
print(f"refs {time.time()-t0:.1f}s noise {noise[0]}", flush=True)
for spec in specs:
    tech = create_technique(spec, sc)
    t1 = time.time()
    seq = run_sequence(sc, tech, frames, res, seed=0)
    mse, mclamp, mtop, share = [], [], [], []
    for img, ref in zip(seq.images, refs):
        e = ((img - ref) ** 2).mean(-1)
        mse.append(float(e.mean()))
        q = np.percentile(ref, 99.9)
        ec = ((np.minimum(img, q) - np.minimum(ref, q)) ** 2).mean(-1)
        mclamp.append(float(ec.mean()))
        k = max(1, e.size // 1000)
        srt = np.sort(e.ravel())[::-1]
        mtop.append(float(srt[k:].sum() / e.size))
        share.append(float(srt[:k].sum() / max(e.sum(), 1e-30)))
    st = seq.stats[1:]
    ms = float(np.median(seq.wall_ms[1:]))
    stages = {}
    for s in st:
        for kk, vv in (s.get("ms") or {}).items():
            stages.setdefault(kk, []).append(vv)
    stages = {kk: float(np.median(vv)) for kk, vv in stages.items()}
    rec = {"scene": scene_name, "res": res, "frames": frames, "ref_spp": ref_spp, "spec": spec,
           "mse": float(np.mean(mse[1:])), "mse_clamp999": float(np.mean(mclamp[1:])),
           "mse_no_top01": float(np.mean(mtop[1:])), "top01_share": float(np.mean(share[1:])),
           "ms": ms, "stages": stages, "per_frame": mse, "sel": st[-1].get("selector") if st else None,
           "load": os.getloadavg()[0], "wall_s": time.time() - t1}
    print(json.dumps({k: (round(v, 6) if isinstance(v, float) else v) for k, v in rec.items() if k != "per_frame"}), flush=True)
    with open(out, "a") as f:
        f.write(json.dumps(rec) + "\n")
