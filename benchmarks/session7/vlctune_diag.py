"""Firefly pixels of nee-pt:lights=vlc: leaf, records in the leaf, cache size, visible lights missing from the cache."""
import sys
import numpy as np
from dyngi.backend import dr, mi
from dyngi.scene import load_scene
from dyngi.experiments.reference import reference_halves
from dyngi.techniques import Frame, create_technique
spec = sys.argv[1] if len(sys.argv) > 1 else "nee-pt:lights=vlc"
sc = load_scene("warehouse-lights"); res = (160, 90); W = res[0]
tech = create_technique(spec, sc)
NF = 10
for i in range(NF):
    t = sc.frame_time(i); sc.at(t)
    cam = sc.camera(t)
    # leaf records of the tree the next frame's VLC is built from: capture before step (VLC built in step)
    r = tech.step(Frame(i, t, cam, res, seed=0))
ref, _ = reference_halves(sc, t, res, 512, 3)
e = ((r.image - ref) ** 2).mean(-1).ravel()
top = np.argsort(e)[::-1][:14]
print("frame", NF - 1, "mse", e.mean(), "top14 share", e[top].sum() / e.sum())
ms = sc.mi_scene
pix = mi.UInt32(top.astype(np.uint32))
ray = cam.sample_rays(res, pix, mi.Point2f(0.5, 0.5))
si = ms.ray_intersect(ray)
oc = tech.octree; vlc = tech.selector
# the VLC used in the frame was built at begin_frame on the tree before the last adapt: use lookup_prev
leaf = np.asarray(oc.lookup_prev(si.p).numpy()) if hasattr(oc, "lookup_prev") else np.asarray(oc.lookup(si.p).numpy())
h = tech.tris.host_arrays()
P = np.asarray(si.p.numpy()).T if np.asarray(si.p.numpy()).shape[0] == 3 else np.asarray(si.p.numpy())
cen = h["centroid"]
c_leaf, c_light = vlc._host_sets
cnt_prev = getattr(oc, "_prev_counts_host", None)
for j, pi in enumerate(top):
    p = P[j]
    n = len(cen)
    o = mi.Point3f(*[mi.Float(np.full(n, p[k], np.float32)) for k in range(3)])
    tgt = mi.Point3f(*[mi.Float(cen[:, k].astype(np.float32)) for k in range(3)])
    d = tgt - o
    ray2 = mi.Ray3f(o + 1e-3 * dr.normalize(d), dr.normalize(d))
    ray2.maxt = dr.norm(d) * 0.995
    vis = ~np.asarray(ms.ray_test(ray2).numpy())
    cache = set(c_light[c_leaf == leaf[j]].tolist())
    visl = set(np.nonzero(vis)[0].tolist())
    print(f"px ({pi % W},{pi // W}) err {e[pi]:.2f} img {r.image.reshape(-1,3)[pi].mean():.2f} ref {ref.reshape(-1,3)[pi].mean():.3f} "
          f"p {np.round(p, 1)} leaf {leaf[j]} cache {len(cache)} visible {len(visl)} missing {len(visl - cache)} "
          f"extra {len(cache - visl)} depth {np.asarray(oc.leaf_depth.numpy())[leaf[j]] if leaf[j] < oc.leaf_count else -1} "
          f"missing_irr {[(int(k), round(float(h['power'][k] / (4 * np.pi * np.sum((cen[k] - p) ** 2))), 3)) for k in sorted(visl - cache)][:6]}")
