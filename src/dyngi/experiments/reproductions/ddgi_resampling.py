"""``dyngi reproduce ddgi-resampling``: Table 1 (time to equal MAPE) of Majercik et al. 2022 on our analogs.

Protocol (Table 1, Sec. 4): every technique renders *static* frames at 1 spp, accumulated
(progressive), until its accumulated image reaches the MAPE that ``ddgi-resampling`` reaches after
``target_frames`` frames (the paper's 1-3; we use 1, our choice: its first frame); the time to equal
MAPE is the number of frames (from the first) times the technique's median steady frame time (frames
>= 2: the first frame carries the probes' warm-up and the kernel compilation, the second compiles the
reuse kernels). A technique that does not reach the target within ``max_frames`` (a biased one,
``ddgi-primary``, may never) is reported as ``> max_frames``. MAPE = mean |v - ref| / (ref + 0.01)
over pixels and channels (Sec. 4), against Mitsuba's ``path`` reference of the scene's depth.

The same with denoising (the "+Denoising" column; Intel OIDN as our substitute for OptiX, fed with
albedo and normal of the primary hits): each technique's accumulated image is denoised at every frame
and compared with the denoised ``ddgi-resampling`` target; the denoiser's time is not charged.

Scenes (analogs): ``cornell-static`` (Red Ball / Pink Room), ``corridor-rooms`` (Room Door),
``atrium-sun`` (Greek Villa), ``glossy-floor`` (Fig. 4, footprint termination), ``living-room`` (Living
Room, the thin-walled sunlit room; skipped with a note if the scene is absent). Columns: ``restir-pt``
(PT+ReSTIR), ``ddgi-primary`` (Primary DDGI), ``ddgi-secondary``, ``ddgi-resampling``. Beside them the
paper's Table 1 (RTX 3090, 1920x1080) and Table 2 per-stage averages; compare ratios, not milliseconds.
``--quick``: 48x27, few frames, 64-spp references (a smoke run; the ratios are then very noisy).

Figures measured with it: docs/benchmarks.md.
"""
from __future__ import annotations

import csv
import os

import numpy as np

from .. import cluster
from ..reproduce import paper_table, register_experiment
from ._summary import write_summary

PAPER = ("Majercik, Mueller, Keller, Nowrouzezahrai, McGuire, \"Dynamic Diffuse Global Illumination "
         "Resampling\", Computer Graphics Forum 41(1), 2022")
SCENES = ("cornell-static", "corridor-rooms", "atrium-sun", "glossy-floor", "living-room")
TECHNIQUES = ("restir-pt", "ddgi-primary", "ddgi-secondary", "ddgi-resampling")
ANALOG = {"cornell-static": "RED BALL / PINK ROOM", "corridor-rooms": "ROOM DOOR", "atrium-sun": "GREEK VILLA",
          "glossy-floor": "(Fig. 4; not in Table 1)", "living-room": "LIVING ROOM"}
# Table 1 (frames, ms, MAPE) for PT+ReSTIR / +Secondary DDGI / +DDGI Resampling
TABLE1 = {
    "GREEK VILLA": ((129, 2908.00, 0.573), (8, 113.52, 0.578), (1, 19.83, 0.572)),
    "LIVING ROOM": ((315, 17157.04, 0.366), (1, 10.82, 0.366), (3, 56.57, 0.365)),
    "PINK ROOM": ((29, 1423.70, 0.384), (9, 97.21, 0.390), (1, 16.85, 0.383)),
    "RED BALL": ((109, 1381.71, 0.140), (29, 254.17, 0.142), (1, 13.37, 0.140)),
    "ROOM DOOR": ((4095, 77278.05, 0.206), (79, 748.51, 0.200), (1, 13.28, 0.199)),
    "SPLIT ROOM": ((150, 1854.92, 0.162), (27, 202.42, 0.162), (1, 10.92, 0.161)),
    "Average": ((804.50, 17000.57, 0.305), (25.50, 237.77, 0.306), (1.33, 21.81, 0.303)),
}
TABLE2_AVG = {"restir-pt": (26.37, 1.09, None), "ddgi-secondary": (7.40, 1.35, 0.96),
              "ddgi-resampling": (10.86, 3.04, 0.97)}   # trace & shade, resampling, update (ms)
QUICK = {"scenes": ("cornell-static", "atrium-sun", "living-room"), "res": (48, 27), "max_frames": 24,
         "ref_spp": 64, "target_frames": 1}
FULL = {"scenes": SCENES, "res": (96, 54), "max_frames": 128, "ref_spp": 512, "target_frames": 1}


def _mape(img, ref):
    from ...metrics.image import mape
    return mape(img, ref)


def run_technique(scene, name: str, res, frames: int, ref, aux=None, stop_at=None, stop_at_dn=None,
                  seed: int = 0) -> dict:
    """``frames`` static frames of ``name`` accumulated; per-frame MAPE (and denoised MAPE with ``aux``).

    Stops early once both targets (``stop_at``, ``stop_at_dn``) are reached. Returns
    ``{'mape', 'mape_dn', 'ms', 'table2'}`` (per frame)."""
    from ...techniques import create_technique
    from ..denoise import denoise
    from ..runner import run_sequence

    tech = create_technique(name, scene, {})
    out = {"mape": [], "mape_dn": [], "ms": [], "table2": []}

    def on_frame(i, frame, r):
        out["table2"].append(r.stats.get("table2_ms"))
        img = np.asarray(r.image)
        out["mape"].append(_mape(img, ref) if np.all(np.isfinite(img)) else float("nan"))
        if aux is not None:
            out["mape_dn"].append(_mape(denoise(img, *aux), ref))
        done = stop_at is not None and out["mape"][-1] <= stop_at
        done_dn = aux is None or (stop_at_dn is not None and out["mape_dn"][-1] <= stop_at_dn)
        return done and done_dn and i + 1 >= MIN_FRAMES

    seq = run_sequence(scene, tech, 0, res, seed=seed, times=[scene.frame_time(0)] * frames, on_frame=on_frame,
                       keep_images=False)
    out["ms"] = seq.wall_ms
    return out


def frames_to_reach(mapes, target):
    """1-based frame count at which the accumulated MAPE first is <= ``target``; None if never."""
    hit = [i for i, m in enumerate(mapes) if np.isfinite(m) and m <= target]
    return hit[0] + 1 if hit else None


MIN_FRAMES = 6
"""Every technique runs at least this many frames: its frame time is the median of frames 2.. (frame 0
warms the probes up and compiles, frame 1 compiles the reuse kernels)."""


def steady_ms(ms) -> float:
    return float(np.median(ms[2:])) if len(ms) > 2 else float(ms[-1])


def run_scene(scene_name: str, cfg: dict, quiet: bool = True) -> dict:
    from ...scene import load_scene
    from ..denoise import aux_buffers, available
    from ..reference import reference_image, scene_max_depth

    scene = load_scene(scene_name)
    res = cfg["res"]
    t0 = scene.frame_time(0)
    scene.at(t0)
    ref = reference_image(scene, t0, res, cfg["ref_spp"], scene_max_depth(scene))
    aux = aux_buffers(scene, scene.camera(t0), res) if available() else None
    k = cfg["target_frames"]
    base = run_technique(scene, "ddgi-resampling", res, k, ref, aux)
    target = base["mape"][k - 1]        # the accumulated image of its first k frames
    target_dn = base["mape_dn"][k - 1] if aux is not None else None
    fig = {"scene": scene_name, "analog": ANALOG[scene_name], "target_mape": target, "target_mape_dn": target_dn,
           "res": list(res), "techniques": {}}
    for name in TECHNIQUES:
        r = run_technique(scene, name, res, cfg["max_frames"], ref, aux, stop_at=target, stop_at_dn=target_dn)
        ms = steady_ms(r["ms"])
        n = frames_to_reach(r["mape"], target)
        n_dn = frames_to_reach(r["mape_dn"], target_dn) if aux is not None else None
        t2 = [x for x in r["table2"][2:] if x]
        fig["techniques"][name] = {
            "frame_ms": ms, "frames": n, "time_ms": (n * ms if n else None),
            "frames_dn": n_dn, "time_dn_ms": (n_dn * ms if n_dn else None),
            "final_mape": r["mape"][-1], "frames_run": len(r["mape"]),
            "nonfinite_frames": int(np.sum(~np.isfinite(r["mape"]))),
            "table2_ms": ({kk: float(np.mean([x[kk] for x in t2])) for kk in t2[0]} if t2 else None)}
        if not quiet:
            print(f"  {scene_name} {name}: {n} frames x {ms:.1f} ms (target MAPE {target:.3f})", flush=True)
    return fig


def _fmt_time(t, n, cap):
    return f"{n} x = {t:.0f} ms" if n else f"> {cap} frames"


def _speedup(fig, name, key="time_ms", cap=None):
    a, b = fig["techniques"]["restir-pt"].get(key), fig["techniques"][name].get(key)
    if b and a:
        return f"{a / b:.1f}x"
    if b and not a:
        ms = fig["techniques"]["restir-pt"]["frame_ms"]
        return f"> {cap * ms / b:.1f}x"
    return "n/a"


def _tables(figs, cfg):
    cap = cfg["max_frames"]
    lines = ["| scene (paper analog) | target MAPE | " + " | ".join(TECHNIQUES) + " | resampling vs restir-pt |",
             "|---|---|" + "---|" * len(TECHNIQUES) + "---|"]
    for f in figs:
        cells = [_fmt_time(f["techniques"][n]["time_ms"], f["techniques"][n]["frames"], cap) for n in TECHNIQUES]
        lines.append(f"| {f['scene']} ({f['analog']}) | {f['target_mape']:.3f} | " + " | ".join(cells)
                     + f" | {_speedup(f, 'ddgi-resampling', cap=cap)} |")
    dn = ["| scene, denoised | target MAPE | " + " | ".join(TECHNIQUES) + " | resampling vs restir-pt |",
          "|---|---|" + "---|" * len(TECHNIQUES) + "---|"]
    for f in figs:
        if f["target_mape_dn"] is None:
            continue
        cells = [_fmt_time(f["techniques"][n]["time_dn_ms"], f["techniques"][n]["frames_dn"], cap)
                 for n in TECHNIQUES]
        dn.append(f"| {f['scene']} | {f['target_mape_dn']:.3f} | " + " | ".join(cells)
                  + f" | {_speedup(f, 'ddgi-resampling', 'time_dn_ms', cap)} |")
    cost = ["| scene | technique | frame ms | trace & shade | resampling | update |", "|---|---|---|---|---|---|"]
    for f in figs:
        for n in TECHNIQUES:
            t = f["techniques"][n]
            t2 = t["table2_ms"] or {}
            cost.append(f"| {f['scene']} | {n} | {t['frame_ms']:.1f} | "
                        + " | ".join(f"{t2[k]:.1f}" if k in t2 else "-" for k in ("trace & shade", "resampling",
                                                                                   "update")) + " |")
    return "\n".join(lines), "\n".join(dn), "\n".join(cost)


def _paper_rows():
    rows = []
    for sc, (pt, sec, rs) in TABLE1.items():
        rows.append((f"{sc}: time to equal MAPE (PT+ReSTIR / Secondary / Resampling)",
                     f"{pt[0]:g} fr {pt[1]:.0f} ms / {sec[0]:g} fr {sec[1]:.0f} ms / {rs[0]:g} fr {rs[1]:.1f} ms "
                     f"(MAPE {rs[2]:.3f}); resampling {pt[1] / rs[1]:.0f}x faster", "see the tables above"))
    for n, (ts, rsm, up) in TABLE2_AVG.items():
        rows.append((f"Table 2 average, {n}", f"trace & shade {ts} ms, resampling {rsm} ms, update "
                     f"{up if up is not None else '-'} ms", "see the cost table above"))
    return rows


@register_experiment("ddgi-resampling", "DDGI Resampling Table 1: time to equal MAPE of restir-pt, ddgi-primary, "
                     "ddgi-secondary, ddgi-resampling (with and without denoising) on five analog scenes", PAPER)
def reproduce_ddgi_resampling(out_dir: str, quick: bool = False, quiet: bool = True) -> str:
    from ...scene import builtin_names

    cfg = QUICK if quick else FULL
    have = set(builtin_names())
    notes = [f"`{sc}` skipped: the scene is not in this build." for sc in cfg["scenes"] if sc not in have]
    names = [sc for sc in cfg["scenes"] if sc in have]   # independent runs: tasks of the executor (--cluster)
    figs = list(cluster.run_named(names, run_scene, [(sc, cfg, quiet) for sc in names], "reproduce ddgi-resampling",
                                  quiet).values())
    notes += [f"failed and left out: {f}" for f in cluster.failure_lines()]
    t1, t1dn, cost = _tables(figs, cfg)
    os.makedirs(out_dir, exist_ok=True)
    with open(os.path.join(out_dir, "table1.csv"), "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["scene", "technique", "target_mape", "frames", "frame_ms", "time_ms", "frames_denoised",
                    "time_denoised_ms", "final_mape"])
        for f in figs:
            for n, t in f["techniques"].items():
                w.writerow([f["scene"], n, f["target_mape"], t["frames"], t["frame_ms"], t["time_ms"],
                            t["frames_dn"], t["time_dn_ms"], t["final_mape"]])
    md = "\n".join([
        f"# reproduce ddgi-resampling ({'quick' if quick else 'full'} run)", "",
        "DDGI Resampling: " + PAPER + ".", "",
        f"Table 1 protocol at {cfg['res'][0]}x{cfg['res'][1]}: static frames at 1 spp accumulated until each "
        f"technique reaches the MAPE `ddgi-resampling` has after {cfg['target_frames']} frame(s); time = "
        f"frames x median steady frame time; at most {cfg['max_frames']} frames; reference Mitsuba `path` at "
        f"{cfg['ref_spp']} spp. CPU (LLVM) timings, not the paper's RTX 3090: compare ratios.", "",
        "## Time to equal MAPE", "", t1, "", "## Time to equal MAPE, denoised (OIDN for OptiX)", "", t1dn, "",
        "## Cost per frame by component (Table 2's grouping; ms)", "", cost, "",
        "## The paper's figures", "", paper_table(_paper_rows()), "",
        *(["## Notes", ""] + [f"* {n}" for n in notes] + [""] if notes else [])])
    status = {}
    for f in figs:
        for n, t in f["techniques"].items():
            s = status.setdefault(n, {"failed": False, "nonfinite_frames": 0, "nonfinite_pixels": "n/a"})
            s["nonfinite_frames"] += t["nonfinite_frames"]
            s["failed"] = s["failed"] or t["nonfinite_frames"] > 0
    config = {k: list(v) if isinstance(v, tuple) else v for k, v in cfg.items()}
    paper = {"experiment": "ddgi-resampling", "quick": quick, "paper": PAPER, "config": config, "figures": figs,
             "notes": notes}
    return write_summary(out_dir, md, {"summary.json": {"techniques": status}, "paper.json": paper})
