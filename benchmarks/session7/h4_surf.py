import numpy as np, sys
from dyngi.backend import dr, mi
from dyngi.scene import load_scene
from dyngi.techniques import Frame
from dyngi.probes.ddgi_plus import DDGIPlusVolume
name = sys.argv[1]
sc = load_scene(name); cam = sc.camera(0.0); res = (64, 36)
ref = np.asarray(mi.render(sc.mi_scene, sensor=cam.to_sensor(res, 512), integrator=mi.load_dict({"type": "path", "max_depth": 12}), spp=512), np.float64)
lum = lambda x: x @ np.array([0.2126, 0.7152, 0.0722])
n = res[0]*res[1]
idx = dr.arange(mi.UInt32, n)
ray = cam.sample_rays(res, idx, mi.Point2f(0.5, 0.5))
si = sc.mi_scene.ray_intersect(ray)
Le = si.emitter(sc.mi_scene).eval(si)
for att in sys.argv[2].split(","):
    vol = DDGIPlusVolume(sc, {"rays_per_probe": 256, "emission_attenuation": att, "irradiance_gamma": 1.0})
    for i in range(30):
        vol.update(Frame(i, 0.0, cam, res, seed=0))
    acc = 0
    for k in range(8):
        smp = mi.load_dict({"type": "independent"}); smp.seed(k, n)
        L = vol.radiance(si, -ray.d, smp.next_2d(), si.is_valid(), u1=smp.next_1d(), sampler=smp, delta_lights=True) + Le
        acc = acc + np.stack([np.asarray(L[c]) for c in range(3)], -1).reshape(res[1], res[0], 3)
    img = acc / 8
    e = lum(img) - lum(ref)
    print(f"{name} {att}: DDGI+ shaded image mean {lum(img).mean():.4f} vs ref {lum(ref).mean():.4f} ({lum(img).mean()/lum(ref).mean()-1:+.3f}), relMSE {(e**2/(lum(ref)**2+1e-2)).mean():.4f}")
