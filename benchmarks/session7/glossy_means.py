import sys, glob, numpy as np
from dyngi import backend as b
b.set_device("cpu")
from dyngi.backend import mi
from dyngi.scene import load_scene
from dyngi.experiments.reference import reference_halves
d, scene_path, depth = sys.argv[1], sys.argv[2], int(sys.argv[3])
res = tuple(int(x) for x in sys.argv[4].split("x")); spp = int(sys.argv[5])
sc = load_scene(scene_path)
def load(p): return np.asarray(mi.Bitmap(p), np.float64)[..., :3]
def lum(a): return a @ [0.2126, 0.7152, 0.0722]
techs = sys.argv[6:]
n = len(glob.glob(f"{d}/{techs[0]}/frame_*.exr"))
R = np.mean([lum(reference_halves(sc, sc.frame_time(i), res, spp, depth)[0]) for i in range(1, n)], axis=0)
for t in techs:
    fr = sorted(glob.glob(f"{d}/{t}/frame_*.exr"))
    I = np.mean([lum(load(p)) for p in fr[1:]], axis=0)
    print(f"{t}: mean luminance {I.mean():.4f}, reference {R.mean():.4f}, ratio {I.mean() / R.mean():.3f}; "
          f"pixels > 2x reference (+1e-3): {np.mean(I > 2 * R + 1e-3):.3f}; < 0.5x: {np.mean(I < 0.5 * R - 1e-3):.3f}")
