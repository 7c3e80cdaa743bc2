import sys
sys.path.insert(0, "/work/main/tests")
from helpers import jit_kernel_hashes
from dyngi.backend import dr
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
SCENE = sys.argv[1]
for spec in sys.argv[2:]:
    sc = load_scene(SCENE)
    tech = create_technique(spec, sc)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    seen = set(); new = []
    for f in range(8):
        dr.kernel_history()
        t = sc.frame_time(f); sc.at(t)
        tech.step(Frame(f, t, sc.camera(t), (24, 16), seed=0))
        h = jit_kernel_hashes(); new.append(len(h - seen)); seen |= h
    print(spec, new, flush=True)
