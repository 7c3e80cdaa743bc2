"""Does a refactoring change what techniques render? Snapshot, then compare.

``snapshot OUT.npz --suite S``: render each technique spec of suite ``S`` for a few frames on each of its
scenes (fixed seeds, small resolution) and store every frame's image and indirect image, plus the suite's
extras. Run it once on the tree before the change (``PYTHONPATH=/path/to/old/src``, e.g. from
``git archive <rev> src | tar -x -C /tmp/before``) and once after. ``compare A.npz B.npz``: per entry,
bit-identical or the largest difference; where not identical, a per-pixel two-sample z-test over the
``--seeds`` independent renders of the last frame (Sidak-corrected over pixels, alpha 0.01) decides whether
the two agree in distribution.

Suites:

* ``techniques`` (default): the transport users on three scenes, plus the VPL radiosity estimator on fixed
  surface points (``vpl/radiosity.py``);
* ``transport``: the techniques moved onto the one path walk (the DDGI Resampling family's glossy
  recursions, ``nee-pt`` with a fixed and with its learning light and direction samplers), 12 seeds each
  (a walk may draw its random numbers in its own order);
* ``probes``: every probe technique of the DDGI family on one dynamic scene, plus the DDGI+ volume's
  atlases after each update (the one probe pipeline);
* ``lights``: every light sampler of ``nee-pt`` and the walk (``path:lights=``, ``path:directions=cdq``),
  and each ``visibility_reuse`` option of ReSTIR DI (issue 37: the light and direction layout);
* ``vpl``: the VPL techniques (``mir``, ``smcir``, ``tcas``, ``ir``) on a dynamic and a glass scene.

    .venv/bin/python benchmarks/before_after.py snapshot /tmp/before.npz --suite probes
    .venv/bin/python benchmarks/before_after.py compare /tmp/before.npz /tmp/after.npz

Recorded in ``docs/transport.md`` ("Renders before and after; the probe techniques' before/after records are
in git history"), beside the command, resolution, seeds and machine load of each run.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

SCENES = ("cornell-static", "glossy-floor", "light-behind-glass")
SUITES = {
    "techniques": {
        "scenes": SCENES, "res": "48x32", "frames": 3, "seeds": 1, "extras": ("radiosity",),
        "techniques": ("path", "path:max_depth=3", "restir-pt:candidates=4:spatial=2",
                       "restir-pt:candidates=4:max_depth=2",
                       "ddgi-primary:candidates=4:probe_counts=3:rays_per_probe=16:warmup=1",
                       "ddgi-secondary:candidates=4:probe_counts=4:rays_per_probe=32:warmup=1:max_glossy=2",
                       "ddgi-resampling:candidates=4:probe_counts=4:rays_per_probe=32:warmup=1:max_glossy=1",
                       "nee-pt", "ir")},
    "transport": {
        "scenes": SCENES, "res": "32x18", "frames": 2, "seeds": 12, "extras": (),
        "techniques": ("ddgi-primary:candidates=4:probe_counts=3:rays_per_probe=16:warmup=1",
                       "ddgi-secondary:candidates=4:probe_counts=3:rays_per_probe=16:warmup=1:progressive=false",
                       "ddgi-resampling:candidates=4:probe_counts=3:rays_per_probe=16:warmup=1:progressive=false",
                       "nee-pt:lights=power", "nee-pt", "nee-pt:lights=vlc:directions=cdq")},
    "probes": {
        "scenes": ("cornell-moving-box",), "res": "32x18", "frames": 4, "seeds": 1, "extras": ("ddgi-plus-volume",),
        "techniques": ("ddgi:probe_counts=4:rays_per_probe=32:warmup=2",
                       "qddgi:probe_counts=4:warmup=2:update_offscreen=true",
                       "probes-reference:probe_counts=3:texels=8:rays_per_texel=4",
                       "adgi:probe_counts=4:static_chains=256:dynamic_chains=64:warmup=2:warmup_rays=32:"
                       "reclassify_interval=2",
                       "isddgi:probe_counts=4:warmup=1:reclassify_interval=2")},
    "lights": {
        "scenes": SCENES, "res": "32x18", "frames": 3, "seeds": 1, "extras": (),
        "techniques": ("nee-pt:lights=lighttree", "nee-pt:lights=sll", "nee-pt:lights=sll-oracle",
                       "nee-pt:lights=uniform", "nee-pt:lights=vlc", "nee-pt:lights=power",
                       "restir-pt:candidates=4:visibility_reuse=none",
                       "restir-pt:candidates=4:visibility_reuse=candidate",
                       "restir-pt:candidates=4:visibility_reuse=final",
                       "path:lights=lighttree", "path:directions=cdq")},
    "vpl": {
        "scenes": ("cornell-moving-box", "light-behind-glass"), "res": "32x18", "frames": 3, "seeds": 1,
        "extras": (), "techniques": ("mir", "smcir", "tcas", "ir")},
}
PLUS = {"probe_counts": "4", "rays_per_probe": 32, "warmup": 2}
"""The DDGI+ volume's settings in the ``probes`` suite."""


def snapshot(out, res, frames, seeds, techniques, scenes, extras=("radiosity",)):
    from dyngi import backend
    backend.set_device("cpu")
    from dyngi.experiments.runner import run_sequence
    from dyngi.scene import load_scene
    from dyngi.techniques.base import create_technique, parse_spec

    data = {}
    for sc_name in scenes:
        for spec_text in techniques:
            spec = parse_spec(spec_text)
            for s in range(seeds):
                sc = load_scene(sc_name)
                tech = create_technique(spec.name, sc, spec.params)
                r = run_sequence(sc, tech, frames, res, seed=s)
                for i, img in enumerate(r.images):
                    data[f"{sc_name}|{spec_text}|{s}|{i}|image"] = img
                    if r.indirect[i] is not None:
                        data[f"{sc_name}|{spec_text}|{s}|{i}|indirect"] = r.indirect[i]
            print(sc_name, spec_text, flush=True)
    if "radiosity" in extras:
        _radiosity(data, scenes)
    if "ddgi-plus-volume" in extras:
        _ddgi_plus(data, scenes, res, frames, seeds)
    np.savez_compressed(out, **data)


def _radiosity(data, scenes):
    """The VPL radiosity estimator on fixed surface points of each scene (vpl/radiosity.py)."""
    from dyngi.backend import dr, mi
    from dyngi.scene import load_scene
    from dyngi.vpl.radiosity import estimate_radiosity
    for sc_name in scenes:
        sc = load_scene(sc_name)
        sc.at(0.0)
        rng = np.random.default_rng(1)
        n = 64
        cam = sc.camera(0.0)
        u = rng.random((n, 2)).astype(np.float32)
        ray = cam.sample_rays((8, 8), dr.arange(mi.UInt32, n), mi.Point2f(u[:, 0], u[:, 1]))
        si = sc.mi_scene.ray_intersect(ray)
        ok = np.asarray(si.is_valid())
        p = np.stack([np.asarray(si.p[k]) for k in range(3)], 1)[ok]
        nn = np.stack([np.asarray(si.n[k]) for k in range(3)], 1)[ok]
        L, rays = estimate_radiosity(sc.mi_scene, p, nn, np.arange(len(p), dtype=np.uint64) * 7919, 16, 4)
        data[f"{sc_name}|radiosity|0|0|L"] = L


def _ddgi_plus(data, scenes, res, frames, seeds):
    """The DDGI+ volume (probes/ddgi_plus.py): its atlases after each update."""
    from dyngi.probes.ddgi_plus import DDGIPlusVolume
    from dyngi.scene import load_scene
    from dyngi.techniques.base import Frame
    for scene in scenes:
        for s in range(seeds):
            sc = load_scene(scene)
            vol = DDGIPlusVolume(sc, PLUS)
            for i in range(frames):
                t = i / 30.0
                sc.at(t)
                vol.update(Frame(i, t, sc.camera(t), res, seed=s * 1000 + i))
                st = vol.volume.state
                data[f"{scene}|ddgi-plus-volume|{s}|{i}|irradiance"] = np.asarray(st.irradiance).copy()
                data[f"{scene}|ddgi-plus-volume|{s}|{i}|distance"] = np.asarray(st.distance).copy()
    print("ddgi-plus-volume", flush=True)


def compare(a_path, b_path):
    a, b = np.load(a_path), np.load(b_path)
    keys = sorted(set(a.files) | set(b.files))
    missing = [k for k in keys if k not in a.files or k not in b.files]
    groups = {}
    for k in keys:
        if k in missing:
            continue
        sc, tech, s, i, kind = k.split("|")
        groups.setdefault((sc, tech, kind), []).append(k)
    ok_all = True
    for (sc, tech, kind), ks in sorted(groups.items()):
        same = all(np.array_equal(a[k], b[k], equal_nan=True) for k in ks)
        if same:
            print(f"{sc:20s} {tech:40s} {kind:9s} bit-identical ({len(ks)} arrays)")
            continue
        diff = max(float(np.nanmax(np.abs(a[k] - b[k]))) for k in ks)
        # per-pixel z-test of the last frame over seeds (independent renders)
        last = max(int(k.split("|")[3]) for k in ks)
        sel = sorted(k for k in ks if int(k.split("|")[3]) == last)
        A = np.stack([a[k] for k in sel]).astype(np.float64)
        B = np.stack([b[k] for k in sel]).astype(np.float64)
        n = len(sel)
        if n < 2:
            print(f"{sc:20s} {tech:40s} {kind:9s} differs (max |d| {diff:.3g}); one seed: no z-test")
            ok_all = False
            continue
        var = (A.var(0, ddof=1) + B.var(0, ddof=1)) / n
        z = (A.mean(0) - B.mean(0)) / np.sqrt(np.maximum(var, 1e-30))
        z = np.where(var > 0, z, 0.0)
        from scipy.stats import norm
        alpha = 1.0 - (1.0 - 0.01) ** (1.0 / z.size)
        crit = norm.isf(alpha / 2)
        rej = int(np.sum(np.abs(z) > crit))
        print(f"{sc:20s} {tech:40s} {kind:9s} differs (max |d| {diff:.3g}); z-test over {n} seeds: "
              f"{rej} of {z.size} pixel-channels beyond |z| > {crit:.2f}; mean {A.mean():.5g} vs {B.mean():.5g}")
        ok_all &= rej == 0
    if missing:
        print("missing in one snapshot:", missing[:10])
    return 0 if ok_all and not missing else 1


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("snapshot")
    s.add_argument("out")
    s.add_argument("--suite", default="techniques", choices=sorted(SUITES))
    s.add_argument("--res", help="WxH (default: the suite's)")
    s.add_argument("--frames", type=int, help="default: the suite's")
    s.add_argument("--seeds", type=int, help="default: the suite's")
    s.add_argument("--techniques", help="';'-separated specs (default: the suite's)")
    s.add_argument("--scenes", help="','-separated (default: the suite's)")
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    args = ap.parse_args()
    if args.cmd == "snapshot":
        su = SUITES[args.suite]
        w, h = (int(x) for x in (args.res or su["res"]).split("x"))
        techs = [t for t in args.techniques.split(";") if t] if args.techniques else list(su["techniques"])
        scenes = args.scenes.split(",") if args.scenes else list(su["scenes"])
        snapshot(args.out, (w, h), args.frames or su["frames"], args.seeds or su["seeds"], techs, scenes,
                 su["extras"])
        return 0
    return compare(args.a, args.b)


if __name__ == "__main__":
    sys.exit(main())
