import numpy as np, sys
import dyngi.backend
from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
scene = load_scene("corridor-rooms")
spec = sys.argv[1] if len(sys.argv) > 1 else "isddgi:probe_counts=16,3,8"
tech = create_technique(spec, scene)
pos = tech.volume.grid.base_positions()
room = (pos[:, 0] > 3.9) & (pos[:, 0] < 8.1) & (pos[:, 2] > 0.9) & (pos[:, 2] < 5.1)
print("room probes", room.sum(), room.mean())
# probes that can see into the room through the door: corridor probes near x in [4,8]
res = (16, 12); fr = 0
for t, n in ((0.9, 10), (1.2, 10)):
    scene.at(t)
    for _ in range(n):
        r = tech.step(Frame(fr, t, scene.camera(t), res, seed=0))
        pl = tech.planner; st = pl.state
        plan = tech.last_plan
        imp = plan.info.importance.sum(1); ids = plan.probe_ids.astype(np.int64)
        frac = imp[room[ids]].sum() / max(imp.sum(), 1)
        Fp = st.F > 0
        print(fr, "imp", imp.sum(), "room frac %.2f" % frac, "F>0 room", Fp[room].sum(), "out", Fp[~room].sum(),
              "dyn", r.stats.get("dynamic_rays"), "chk", r.stats.get("check_rays"), "x", np.mean(st.x[room]), np.mean(st.x[~room]), "drop", r.stats.get("importance_dropped"))
        if fr in (9, 11):
            out = np.flatnonzero(Fp & ~room)
            print("  out probes", out[:20], pos[out[:10]].round(1).tolist())
        fr += 1
