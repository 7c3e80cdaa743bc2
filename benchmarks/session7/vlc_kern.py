import time, sys
from dyngi.backend import dr, mi
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
sc = load_scene(sys.argv[1]); tech = create_technique(sys.argv[2], sc)
dr.set_flag(dr.JitFlag.KernelHistory, True)
for i in range(6):
    t = sc.frame_time(i); sc.at(t); t0=time.time()
    tech.step(Frame(i, t, sc.camera(t), (32,32)))
    h = dr.kernel_history(); 
    print(i, round((time.time()-t0)*1e3), len([k for k in h if k['type']==dr.KernelType.JIT]), sum(1 for k in h if k['type']==dr.KernelType.JIT and not k.get('cache_hit', True)))
