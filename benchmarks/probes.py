"""Probe-volume benchmarks (DDGI): prints a markdown table.

1. probe-update rays/s vs raw ``ray_intersect`` rays/s on the same rays (the update's own plan), same run;
2. the default ``ddgi`` frame (2048 probes x 256 rays, 640x360) vs a 1-spp frame of
   Mitsuba's own ``path`` integrator at the same resolution;
3. frames to re-converge after the Cornell light jumps;
4. frame time vs probe count (8^3 .. 32^3; 64^3 with --big).

Usage: ``python benchmarks/probes.py [--quick] [--big] [--frame-only] [--rounds R] [--scenes]
[--device cpu|cuda]``. Timings are medians over
repeated frames after warm-up (kernel compilation excluded).

Recorded in ``docs/techniques/ddgi.md`` ("Probe update against raw `ray_intersect`; equal rays; equal time;
re-convergence; scaling with the probe count"), beside the command, resolution, seeds and machine load of each
run.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from dyngi.backend import device_info, dr, mi, set_device
from dyngi.errors import DyngiError
from dyngi.probes import ProbeGrid, ProbeVolume, UniformSFDirections
from dyngi.probes.pipeline import UPDATE_STAGES
from dyngi.scene import load_scene
from dyngi.sampling.rng import make_sampler
from dyngi.techniques.base import Frame, create_technique

from common import shared_scene


def median_time(fn, reps: int, warm: int = 2) -> float:
    for _ in range(warm):
        fn()
    ts = []
    for _ in range(reps):
        dr.sync_thread()
        t0 = time.perf_counter()
        fn()
        dr.sync_thread()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def raw_intersect_timers(scene, tech):
    """Timers (seconds, best of 3 back-to-back passes) of full ``ray_intersect`` and of the preliminary
    test on exactly the rays one update traces, of ``ray_test`` on shadow rays from their hits to the
    light (where the update casts one: front-face hits with the light sample above the surface), and the
    counts of probe rays and shadow rays.

    The same plan as the technique's update (its active probes, its rays per
    probe, a frame's rotation): the rays of inactive probes (outside the room,
    inside walls) are cheaper and would flatter the raw rate.
    """
    vol = tech.volume
    plan = tech.pipeline.planner.plan(5, 0, vol.active_indices())
    origin = dr.gather(mi.Point3f, vol.device.positions, plan.probe)
    ray = mi.Ray3f(origin, plan.direction)
    dr.eval(ray)

    def full():
        si = scene.mi_scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=False)
        dr.eval(si.t, si.p, si.n, si.sh_frame.n, si.uv, si.shape)

    def prelim():
        pi = scene.mi_scene.ray_intersect_preliminary(ray, coherent=False)
        dr.eval(pi.t, pi.prim_index, pi.shape)

    # the update's shadow rays: from the hits to a point on a light (Mitsuba's emitter sampling)
    si = scene.mi_scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=False)
    ok = si.is_valid() & (dr.dot(si.n, ray.d) < 0.0)
    u = make_sampler(dr.width(ray.d), 0, 5, 13).next_2d()
    ds, _ = scene.mi_scene.sample_emitter_direction(si, u, False, ok)
    ok &= (ds.pdf != 0.0) & (dr.dot(si.sh_frame.n, ds.d) > 0.0)
    shadow = si.spawn_ray_to(ds.p)
    dr.eval(shadow, ok)

    def test():
        dr.eval(scene.mi_scene.ray_test(shadow, ok))

    def timer(fn):
        def best_of_3():
            ts = []
            for _ in range(3):       # back to back: the raw rate at its best (warm caches), not after a frame
                dr.sync_thread()
                t0 = time.perf_counter()
                fn()
                dr.sync_thread()
                ts.append(time.perf_counter() - t0)
            return min(ts)
        best_of_3()                  # compile
        return best_of_3

    return timer(full), timer(prelim), timer(test), dr.width(plan.direction), int(dr.count(ok)[0])


OTHER_SCENES = ("atrium-sun", "veach-ajar/scene_nopots.xml", "staircase2/scene.xml")


def update_vs_raw(sc, params, res, pairs: int, rows: list, label: str = ""):
    """Probe-update rays/s against raw ``ray_intersect`` on the update's own rays, as ``pairs`` frame/raw
    pairs (the shared machine drifts by up to 1.5x within a minute: each ratio compares an update with
    the raw passes timed right after it). Appends table rows; returns (frame stats, technique, median probe
    rays, median update ms)."""
    tech, _ = ddgi_frames(sc, params, res, 1)
    full_once, pre_once, test_once, n_raw, n_test = raw_intersect_timers(sc, tech)
    stats, upd_ratios, all_ratios, time_ratios, fulls, pres = [], [], [], [], [], []
    for f in range(pairs):
        st = more_frames(tech, sc, res, 10 + f, 1)[0]
        t_full, t_pre, t_test = full_once(), pre_once(), test_once()
        update_s = 1e-3 * update_ms_of(st)
        raw = n_raw / t_full
        probe, shadow = st["rays"]["trace probes"], st["rays"]["shade probes"]   # shadow rays as cast
        upd_ratios.append(probe / update_s / raw)
        all_ratios.append((probe + shadow) / update_s / raw)
        # stricter: raw Mitsuba's time for the same work (full intersections + as many shadow tests) / update time
        time_ratios.append((t_full * probe / n_raw + t_test * shadow / max(n_test, 1)) / update_s)
        stats.append(st)
        fulls.append(raw)
        pres.append(n_raw / t_pre)
    full_rate, pre_rate = float(np.median(fulls)), float(np.median(pres))
    update_ms = float(np.median([update_ms_of(s) for s in stats]))
    probe_rays = med(stats, "rays", "trace probes")
    shadow_rays = med(stats, "rays", "shade probes")

    def spread(v):
        q1, q3 = np.percentile(v, [25, 75])
        return f"{np.median(v):.0%} of full ray_intersect (median of {len(v)} frame/raw pairs; quartiles {q1:.0%}-{q3:.0%})"
    probes = stats[-1]["probes_traced"]
    rows.append((f"{label}raw ray_intersect (full SurfaceInteraction), probe rays ({probes} probes x "
                 f"{stats[-1]['rays_per_probe']})", f"{full_rate / 1e6:.1f} Mrays/s",
                 f"median; best of 3 back-to-back passes timed after each update; preliminary only: "
                 f"{pre_rate / 1e6:.1f} Mrays/s"))
    rows.append((f"{label}probe update (trace, shade with NEE + multi-bounce query, blend, states), probe rays only",
                 f"{probe_rays / (update_ms * 1e-3) / 1e6:.1f} Mrays/s", spread(upd_ratios)))
    rows.append((f"{label}probe update, probe rays + the NEE shadow rays cast ({shadow_rays / probe_rays:.2f} per "
                 "probe ray)", f"{(probe_rays + shadow_rays) / (update_ms * 1e-3) / 1e6:.1f} Mrays/s",
                 spread(all_ratios)))
    rows.append((f"{label}raw time for the update's rays (full ray_intersect of the probe rays + ray_test of as many "
                 "shadow rays as it cast) / update time", f"{np.median(time_ratios):.0%}",
                 "quartiles " + "-".join(f"{q:.0%}" for q in np.percentile(time_ratios, [25, 75]))
                 + f"; update {update_ms:.1f} ms"))
    return stats, tech, probe_rays, update_ms


def update_ms_of(st) -> float:
    """The probe update's time in one frame's stats: the sum of its stages."""
    return sum(st["ms"].get(k, 0.0) for k in UPDATE_STAGES)


def probe_query_time(scene, tech, reps: int, stochastic: bool) -> float:
    """Seconds for the multi-bounce probe lookups alone at the front-face hits of one frame's probe rays:
    ``stochastic`` one texel of one probe (the ``ddgi`` default at hits) or the full 8-probe filter."""
    vol = tech.volume
    plan = tech.pipeline.planner.plan(5, 0, vol.active_indices())
    origin = dr.gather(mi.Point3f, vol.device.positions, plan.probe)
    ray = mi.Ray3f(origin, plan.direction)
    si = scene.mi_scene.ray_intersect(ray, mi.RayFlags.All, False)
    front = si.is_valid() & (dr.dot(si.n, ray.d) < 0.0)
    p, n, wo = mi.Point3f(si.p), mi.Vector3f(si.sh_frame.n), -ray.d
    dr.eval(p, n, wo, front)
    k = [0]

    def once():
        k[0] += 1
        sampler = make_sampler(dr.width(p), 0, k[0], 11) if stochastic else None
        dr.eval(tech.query.irradiance(p, n, wo, active=front, sampler=sampler))

    return median_time(once, reps)


def ddgi_frames(scene, params, res, frames: int, warm: int = 3):
    """A new ``ddgi`` technique and the stats of ``frames`` frames after ``warm`` unmeasured ones."""
    tech = create_technique("ddgi", scene, params)
    more_frames(tech, scene, res, 0, warm)
    return tech, more_frames(tech, scene, res, warm, frames)


def more_frames(tech, scene, res, first: int, frames: int):
    """Stats (with ``wall_ms``) of frames ``first`` .. ``first + frames - 1`` of a ``ddgi`` technique."""
    stats = []
    for f in range(first, first + frames):
        t0 = time.perf_counter()
        r = tech.step(Frame(f, 0.0, scene.camera(0.0), res, seed=0))
        s = dict(r.stats)
        s["wall_ms"] = 1e3 * (time.perf_counter() - t0)
        stats.append(s)
    return stats


def med(stats, key, sub=None):
    vals = [(s[key][sub] if sub else s[key]) for s in stats if (sub is None or sub in s[key])]
    return float(np.median(vals)) if vals else float("nan")


def mitsuba_path_1spp(scene, res, reps: int):
    sensor = scene.camera(0.0).to_sensor(res, 1)
    integ = mi.load_dict({"type": "path", "max_depth": 12})
    k = [0]

    def once():
        k[0] += 1
        img = mi.render(scene.mi_scene, sensor=sensor, integrator=integ, spp=1, seed=k[0])
        dr.eval(img)

    return median_time(once, reps)


def reconvergence_frames(res, margin: float = 0.02, max_frames: int = 150, counts="8"):
    """Frames until the indirect image is back within ``margin`` (mean |diff| / mean) of its new steady state.

    The steady state at the new light position is the mean of 20 frames of a
    volume converged there; the noise floor is the same error for a second,
    independently converged volume; "re-converged" = error < floor + margin.
    Returns (frames or None, floor, error after 1 / 10 / 30 frames).
    """
    sc = load_scene("cornell-moving-light")
    ta, tb = 0.0, 0.5         # light at the left end (x = -0.6), then at the right end (x = +0.6)
    params = {"probe_counts": counts}
    sc.at(tb)
    ref_t = create_technique("ddgi", sc, params)
    ref = 0.0
    for f in range(170):
        ind = ref_t.step(Frame(f, tb, sc.camera(tb), res, seed=5)).indirect
        if f >= 150:
            ref = ref + ind / 20
    other = create_technique("ddgi", sc, params)
    for f in range(150):
        ind = other.step(Frame(f, tb, sc.camera(tb), res, seed=9)).indirect
    denom = ref.mean() + 1e-6
    floor = np.abs(ind - ref).mean() / denom
    sc.at(ta)
    tech = create_technique("ddgi", sc, params)
    for f in range(150):
        tech.step(Frame(f, ta, sc.camera(ta), res, seed=7))
    sc.at(tb)
    errs = {}
    found = None
    for k in range(1, max_frames + 1):
        ind = tech.step(Frame(150 + k, tb, sc.camera(tb), res, seed=7)).indirect
        e = np.abs(ind - ref).mean() / denom
        errs[k] = e
        if found is None and e < floor + margin:
            found = k
        if found is not None and k >= 30:
            break
    return found, floor, errs.get(1), errs.get(10), errs.get(30)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="fewer repetitions, smaller images")
    ap.add_argument("--big", action="store_true", help="include 64^3 probes")
    ap.add_argument("--frame-only", action="store_true", help="only parts 1 and 2 (update rate, frame time)")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved ddgi / Mitsuba rounds for part 2")
    ap.add_argument("--device", default="cpu", choices=("cpu", "cuda"),
                    help="cpu: llvm_ad_rgb (default); cuda: cuda_ad_rgb on an NVIDIA GPU")
    ap.add_argument("--scenes", action="store_true",
                    help="part 1 also on atrium-sun and the real scenes of ../shared/scenes (when present)")
    args = ap.parse_args()
    try:
        set_device(args.device)
    except DyngiError as e:
        raise SystemExit(f"probes.py: error: {e}")
    reps = 3 if args.quick else 7
    res = (640, 360)
    sc = load_scene("cornell-static")

    print(f"device: {device_info()}")
    rows = []
    # -- 1. probe update vs raw ray_intersect, frame by frame --
    stats, tech, probe_rays, update_ms = update_vs_raw(sc, {"probe_counts": "16,8,16"}, res, args.rounds * reps,
                                                       rows)
    query_ms = 1e3 * probe_query_time(sc, tech, reps, stochastic=True)
    filtered_ms = 1e3 * probe_query_time(sc, tech, reps, stochastic=False)
    rows.append((f"of which: multi-bounce lookups alone at the {int(probe_rays)} probe-ray hits (stochastic, "
                 "as in the update)", f"{query_ms:.1f} ms", f"{query_ms / update_ms:.0%} of the update "
                 f"({update_ms:.1f} ms); the full 8-probe filter: {filtered_ms:.1f} ms"))
    if args.scenes:
        for name in OTHER_SCENES:
            path = shared_scene(name) if name.endswith(".xml") else name
            if path is None:
                rows.append((f"{name}: update vs raw", "skipped", "../shared/scenes absent"))
                continue
            update_vs_raw(load_scene(path), {}, res, reps, rows, label=name.split("/")[0] + ": ")
    # -- 2. default ddgi frame vs Mitsuba path 1 spp --
    for k in UPDATE_STAGES + ("primary",):
        rows.append((f"ddgi stage '{k}' ({int(probe_rays)} probe rays, {res[0]}x{res[1]})",
                     f"{med(stats, 'ms', k):.1f} ms", ""))
    # interleaved rounds: the shared machine drifts, so each ratio compares times taken side by side
    ratios, ddgi_all, path_all = [], [], []
    for _ in range(args.rounds):
        _, st = ddgi_frames(sc, {"probe_counts": "16,8,16"}, res, reps, warm=1)
        ddgi_ms = med(st, "total_ms")
        path_ms = 1e3 * mitsuba_path_1spp(sc, res, reps)
        ratios.append(ddgi_ms / path_ms)
        ddgi_all.append(ddgi_ms)
        path_all.append(path_ms)
    rows.append(("ddgi frame total (2048 probes x 256 rays, 640x360)",
                 f"{np.median(ddgi_all):.1f} ms", f"{np.median(ratios):.2f}x Mitsuba path 1 spp (median of "
                 f"{len(ratios)} interleaved rounds; range {min(ratios):.2f}-{max(ratios):.2f})"))
    rows.append(("Mitsuba `path` integrator, 1 spp, 640x360, max_depth 12", f"{np.median(path_all):.1f} ms", ""))
    if args.frame_only:
        _print(rows)
        return
    # -- 3. re-convergence after the light moves --
    k, floor, e1, e10, e30 = reconvergence_frames((160, 90) if args.quick else (320, 180))
    rows.append(("frames to re-converge after the Cornell light jumps 1.2 m (indirect image within noise floor "
                 "+ 2% mean abs. error of its new steady state; hysteresis 0.97)", str(k) if k else "> 150",
                 f"floor {floor:.3f}; error after 1/10/30 frames: {e1:.3f} / {e10:.3f} / {e30:.3f}"))
    # -- 4. scaling with probe count --
    sizes = [8, 16, 24, 32] + ([64] if args.big else [])
    for n in sizes:
        _, st = ddgi_frames(sc, {"probe_counts": str(n), "classify": False, "relocate": False}, (320, 180),
                            2 if n >= 32 else reps, warm=2)
        upd = sum(med(st, "ms", kk) for kk in ("trace probes", "shade probes", "blend"))
        rows.append((f"{n}^3 = {n ** 3} probes x 256 rays: update (trace + shade + blend)", f"{upd:.1f} ms",
                     f"blend {med(st, 'ms', 'blend'):.1f} ms"))

    _print(rows)


def _print(rows):
    print("\n| measurement | value | note |\n|---|---|---|")
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]} |")


if __name__ == "__main__":
    main()
