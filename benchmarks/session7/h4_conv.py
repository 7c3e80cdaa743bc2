import sys, numpy as np
sys.path.insert(0, "tests")
import test_ddgi_plus as T
from dyngi.scene import load_scene
from dyngi.probes.ddgi_plus import DDGIPlusVolume
from dyngi.backend import mi
from dyngi.probes.query import bilinear_gather
from dyngi.sampling.octahedral import direction_to_texel_coords
for name in sys.argv[1].split(","):
  for glossy in (True, False):
    sc = load_scene(name)
    vol = DDGIPlusVolume(sc, {"probe_counts": "4", "rays_per_probe": 512, "hysteresis": 0.95, "warmup": 8,
                              "irradiance_gamma": 1.0, "emission_attenuation": "none", "relocate": False,
                              "classify": False, "probe_glossy": glossy})
    for i in range(40):
        vol.update(T._frame(sc, i))
    pos = vol.volume.positions()
    dirs = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)
    P, D = len(pos), len(dirs)
    probe = mi.UInt32(np.repeat(np.arange(P), D).astype(np.uint32))
    dd = mi.Vector3f(*[mi.Float(np.tile(dirs[:, k], P).astype(np.float32)) for k in range(3)])
    Tt = vol.volume.irradiance_texels
    tex = bilinear_gather(vol.volume.device.irradiance, probe, direction_to_texel_coords(dd, Tt), Tt, 3)
    got = np.stack([np.asarray(tex[c], np.float64) for c in range(3)], -1).reshape(P, D, 3)
    ref = T._reference_probe_irradiance(sc, pos, dirs, 2048)
    lum = np.array([0.2126, 0.7152, 0.0722])
    g, r = got @ lum, ref @ lum
    rel = np.abs(g - r) / np.maximum(r, 1e-3 * r.mean())
    print(name, "glossy", glossy, f"mean {g.mean()/r.mean()-1:+.3f} median {np.median(rel):.3f} 90% {np.quantile(rel,0.9):.3f}")
