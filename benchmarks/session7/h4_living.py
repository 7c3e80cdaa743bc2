import time, numpy as np, sys
from dyngi.backend import dr, mi
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
from dyngi.sampling.gbuffer import render_gbuffer
res = (int(sys.argv[1]), int(sys.argv[2])) if len(sys.argv) > 2 else (80, 45)
sc = load_scene("living-room")
cam = sc.camera(0.0)
t0=time.time()
ref = np.asarray(mi.render(sc.mi_scene, sensor=cam.to_sensor(res, 512), integrator=mi.load_dict({"type": "path", "max_depth": -1}), spp=512), np.float64)
print("ref", round(time.time()-t0,1), ref.mean(axis=(0,1)))
gb = render_gbuffer(sc, cam, res, mi.Point2f(0.5, 0.5))
pos = np.stack([np.asarray(gb.pos[i]) for i in range(3)], -1).reshape(res[1], res[0], 3)
X, H, Z = 3.0, 2.7, 2.5
dwall = np.minimum.reduce([X - np.abs(pos[..., 0]), Z - np.abs(pos[..., 2]), H - pos[..., 1]])
inside = (np.abs(pos[..., 0]) < X + 1e-3) & (np.abs(pos[..., 2]) < Z + 1e-3) & (pos[..., 1] < H + 1e-3)
near = inside & (dwall < 0.3)
print("near-wall pixels", near.mean())
lum = lambda im: im @ np.array([0.2126, 0.7152, 0.0722])
out = {}
for spec in ["ddgi", "ddgi-primary", "ddgi:visibility=true"]:
    tech = create_technique(spec, sc, {})
    acc = []
    t0 = time.time()
    for i in range(16):
        r = tech.step(Frame(i, 0.0, cam, res, seed=0, static=i > 0))
        if i >= 8: acc.append(r.image)
    img = np.mean(acc, 0)
    e = lum(img) - lum(ref)
    rel_near = e[near].mean() / lum(ref)[near].mean()
    rel_far = e[inside & ~near].mean() / lum(ref)[inside & ~near].mean()
    print(spec, round((time.time()-t0)/16*1e3,1), "ms/frame; mean", img.mean(axis=(0,1)), "rel err near walls", round(rel_near,3), "elsewhere", round(rel_far,3))
    out[spec] = img
np.savez("/tmp/h4_living.npz", ref=ref, near=near, **{k.replace(":","_"): v for k, v in out.items()})
import imageio.v3 as iio
def tm(x): return (np.clip((x/(1+x))**(1/2.2),0,1)*255).astype(np.uint8)
iio.imwrite("/tmp/h4_living.png", np.concatenate([tm(ref), tm(out["ddgi"]), tm(out["ddgi-primary"])], 0))
