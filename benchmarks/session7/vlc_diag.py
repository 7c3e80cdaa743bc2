import numpy as np
from dyngi.backend import dr, mi
from dyngi.scene import load_scene
from dyngi.experiments.reference import reference_image
from dyngi.techniques import Frame, create_technique
sc = load_scene("warehouse-lights"); res=(96,54)
tech = create_technique("nee-pt:lights=vlc", sc)
for i in range(5):
    t = sc.frame_time(i); sc.at(t)
    r = tech.step(Frame(i, t, sc.camera(t), res, seed=0))
    ref = reference_image(sc, t, res, 256, 3)
    e = ((r.image - ref)**2).mean(-1)
    idx = np.argsort(e.ravel())[::-1][:5]
    print(i, e.mean(), [(int(j%96), int(j//96), round(float(e.ravel()[j]),2), r.image.reshape(-1,3)[j].mean().round(2), ref.reshape(-1,3)[j].mean().round(2)) for j in idx])
    print("  share of top 20 px:", np.sort(e.ravel())[::-1][:20].sum()/e.sum(), tech.selector.stats())
print("indirect at top pixels:", [(float(r.indirect.reshape(-1,3)[j].mean()), float(r.image.reshape(-1,3)[j].mean())) for j in idx])
