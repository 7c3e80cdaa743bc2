from dyngi.scene import load_scene
from dyngi.techniques import Frame, create_technique
sc = load_scene("tunnel-gate")
a = create_technique("adgi", sc, {})
for f in range(4):
    t = 2.0 + f / 15; sc.at(t)
    r = a.step(Frame(f, t, sc.camera(t), (64, 48), seed=0, ray_budget=39644 if f else None))
print(r.stats["rays"], r.stats["total_rays"], r.stats["v_out"], r.stats["v_in"], r.stats["static_chains_run"])
