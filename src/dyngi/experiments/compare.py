"""``dyngi compare``: several techniques on one animated scene against the ground truth.

Writes into ``out_dir`` (atomically: a temporary folder moved into place at the end):

* ``metrics.csv``     technique x frame x metric (mse, relmse, mape, flip, ssim), ms and rays;
* ``summary.md``      per technique: mean error by metric, |E| and |E'| (SMC-IR Sec. 5.2),
                      ms per frame by stage, rays per frame;
* ``plots/``          error vs frame, error vs cumulative wall time, stage-time bars (matplotlib);
* ``grid_NNNN.png``   for chosen frames: each technique, the reference and the FLIP error map;
* ``side_by_side.mp4`` reference and techniques next to each other, labelled;
* ``<technique>/frame_NNNN.png`` and ``.exr`` every frame, and ``report.html``, self-contained.

Budgets (``--budget``): ``equal-frames`` runs every technique with its own settings;
``equal-rays`` gives every frame of every technique the ray count that the first
technique traced on that frame; ``equal-time`` gives the first technique's wall
time. Techniques honour budgets as documented in their modules.
"""
from __future__ import annotations

import base64
import csv
import html
import os
import sys

import numpy as np

from .. import backend
from ..errors import DyngiError
from ..scene import load_scene
from ..techniques.base import create_technique, get_technique
from .io import atomic_output_dir, check_writable, tonemap_srgb, write_exr, write_json, write_mp4, write_png
from .runner import BUDGETS, run_sequence

METRIC_NAMES = ("mse", "relmse", "mape", "flip", "ssim")
LABELS = {"mse": "MSE", "relmse": "relMSE", "mape": "MAPE", "flip": "FLIP", "ssim": "SSIM"}


def split_params(techniques: list[str], params: dict) -> dict[str, dict]:
    """``tech.key=value`` goes to one technique; ``key=value`` to every technique that has ``key``."""
    out = {t: {} for t in techniques}
    for k, v in (params or {}).items():
        if "." in k:
            t, key = k.split(".", 1)
            if t not in out:
                raise DyngiError(f"--set '{k}' names technique '{t}' which is not compared; "
                                 f"compared techniques: {', '.join(techniques)}")
            out[t][key] = v
        else:
            takers = [t for t in techniques if k in get_technique(t).PARAMS]
            if not takers:
                valid = sorted({p for t in techniques for p in get_technique(t).PARAMS})
                raise DyngiError(f"no compared technique has a parameter '{k}'; valid parameters: "
                                 + (", ".join(valid) or "(none)"))
            for t in takers:
                out[t][k] = v
    return out


def run_compare(scene_name: str, techniques: list[str], out_dir: str, frames: int = 30, res=(160, 120),
                budget: str = "equal-frames", seed: int = 0, ref_spp: int | None = None, quiet: bool = False,
                params: dict | None = None, grid_frames: list[int] | None = None,
                metrics: list[str] | None = None) -> str:
    """Run the comparison and write the outputs described in the module docstring; return ``out_dir``.

    ``metrics``: names from :data:`dyngi.metrics.METRICS` (default all five). HDR-FLIP costs
    ~10 us per pixel on 2 CPU cores (docs/benchmarks.md); leave it out for long sequences
    (the FLIP maps of the image grid are computed regardless).
    """
    from ..metrics import METRICS, compute_all, flip, temporal_errors
    from .reference import reference_image

    names = list(metrics) if metrics else list(METRIC_NAMES)
    for m in names:
        if m not in METRICS:
            raise DyngiError(f"unknown metric '{m}'; valid metrics: {', '.join(sorted(METRICS))}")

    # -- validate everything before any work --
    if not techniques:
        raise DyngiError("no techniques given; e.g. --techniques path,ddgi")
    if len(set(techniques)) != len(techniques):
        raise DyngiError(f"a technique is listed twice in '{','.join(techniques)}'")
    for t in techniques:
        get_technique(t)
    if budget not in BUDGETS:
        raise DyngiError(f"unknown budget '{budget}'; valid budgets: {', '.join(BUDGETS)}")
    if frames < 1:
        raise DyngiError(f"--frames must be >= 1, got {frames}")
    check_writable(out_dir)
    per_tech = split_params(techniques, params or {})
    scene = load_scene(scene_name)
    techs = {t: create_technique(t, scene, per_tech[t]) for t in techniques}
    out_dir = os.path.abspath(out_dir)
    ref_kw = {} if ref_spp is None else {"spp": ref_spp}

    bar = None
    if not quiet:
        from tqdm import tqdm
        bar = tqdm(total=frames * (len(techniques) + 1), desc=f"compare on {scene.name}", unit="frame",
                   file=sys.stderr)

    # -- ground truth (cached) --
    refs = []
    for i in range(frames):
        t = scene.frame_time(i)
        refs.append(reference_image(scene, t, res, **ref_kw))
        if bar is not None:
            bar.update(1)

    # -- run every technique --
    results = {}
    first = None
    for name in techniques:
        kw = {}
        if first is not None and budget != "equal-frames":
            # per-frame budget from the first technique
            kw = {"budgets": first}
        seq = _run_with_budget(scene, techs[name], frames, res, seed, budget, kw.get("budgets"), bar)
        results[name] = seq
        if first is None:
            first = seq
    if bar is not None:
        bar.close()

    # -- metrics --
    rows = []
    summary = {}
    for name, seq in results.items():
        per_frame = []
        for i, img in enumerate(seq.images):
            m = compute_all(np.nan_to_num(np.maximum(img, 0.0)), refs[i], names)
            st = seq.stats[i]
            row = {"technique": name, "frame": i, "time": seq.times[i], **m,
                   "wall_ms": seq.wall_ms[i], "rays": st.get("total_rays", 0)}
            for stage, ms in st.get("ms", {}).items():
                row[f"ms_{stage}"] = ms
            rows.append(row)
            per_frame.append(m)
        tm = temporal_errors(np.stack([np.maximum(np.nan_to_num(x), 0) for x in seq.images]), np.stack(refs))
        steady, steady_ms = seq.steady()
        stage_ms = {}
        for st in steady:
            for k, v in st.get("ms", {}).items():
                stage_ms[k] = stage_ms.get(k, 0.0) + v / len(steady)
        summary[name] = {
            "mean": {k: float(np.mean([f[k] for f in per_frame])) for k in names},
            "E": float(tm["E"]), "E_prime": float(tm["E_prime"]),
            "ms_per_frame": float(np.mean(steady_ms)),
            "stage_ms": stage_ms,
            "rays_per_frame": float(np.mean([s.get("total_rays", 0) for s in steady])),
        }

    # -- outputs --
    with atomic_output_dir(out_dir) as tmp:
        _write_csv(os.path.join(tmp, "metrics.csv"), rows)
        md = _summary_md(scene, techniques, summary, frames, res, budget, seed, names)
        with open(os.path.join(tmp, "summary.md"), "w") as f:
            f.write(md)
        write_json(os.path.join(tmp, "summary.json"), {"scene": scene.name, "frames": frames, "res": list(res),
                                                       "budget": budget, "seed": seed,
                                                       "device": backend.device_info(),
                                                       "techniques": summary})
        for name, seq in results.items():
            os.makedirs(os.path.join(tmp, name), exist_ok=True)
            for i, img in enumerate(seq.images):
                write_png(os.path.join(tmp, name, f"frame_{i:04d}.png"), img)
                write_exr(os.path.join(tmp, name, f"frame_{i:04d}.exr"), img)
        os.makedirs(os.path.join(tmp, "reference"), exist_ok=True)
        for i, r in enumerate(refs):
            write_png(os.path.join(tmp, "reference", f"frame_{i:04d}.png"), r)
        plots = _plots(tmp, rows, techniques, summary, names)
        gframes = grid_frames if grid_frames is not None else sorted({frames // 2, frames - 1})
        grids = [_grid(tmp, i, results, refs, flip) for i in gframes if 0 <= i < frames]
        if frames > 1:
            _side_by_side(os.path.join(tmp, "side_by_side.mp4"), results, refs, scene.fps)
        _report_html(tmp, scene, md, plots, grids, frames > 1)
    return out_dir


def _run_with_budget(scene, tech, frames, res, seed, budget, budgets, bar):
    """run_sequence, with the first technique's per-frame rays or time as this technique's budget."""
    if budgets is None:
        return run_sequence(scene, tech, frames, res, seed=seed, progress=bar)
    from .runner import SequenceResult

    merged = SequenceResult(tech.name)
    wrapped = _Budgeted(tech, None, None)
    # equal time: the first technique's steady median frame time (frame 0 includes kernel compilation,
    # and single frames on a shared CPU are noisy)
    time_budget = float(np.median(budgets.steady()[1]))
    for i in range(frames):
        wrapped.rb = budgets.stats[i].get("total_rays") if budget == "equal-rays" else None
        wrapped.tb = time_budget if budget == "equal-time" else None
        seq = run_sequence(scene, wrapped, 1, res, seed=seed, t0=scene.frame_time(i))
        merged.times += seq.times
        merged.images += seq.images
        merged.indirect += seq.indirect
        merged.stats += seq.stats
        merged.wall_ms += seq.wall_ms
        if bar is not None:
            bar.update(1)
    return merged


class _Budgeted:
    """Wraps a technique so each step receives a ray or time budget (frame index restored)."""

    def __init__(self, tech, ray_budget, time_budget_ms):
        self.tech, self.rb, self.tb = tech, ray_budget, time_budget_ms
        self.name = tech.name
        self.prev_sig = None

    def step(self, frame):
        frame.ray_budget, frame.time_budget_ms = self.rb, self.tb
        frame.index = int(round(frame.time * self.tech.scene.fps))
        sig = self.tech.scene.signature(frame.time)   # static as in run_sequence: nothing moved since the last frame
        frame.static = sig == self.prev_sig
        self.prev_sig = sig
        return self.tech.step(frame)


def _write_csv(path, rows):
    keys = []
    for r in rows:
        for k in r:
            if k not in keys:
                keys.append(k)
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow(r)


def _summary_md(scene, techniques, summary, frames, res, budget, seed, names) -> str:
    info = backend.device_info()
    lines = [f"# {scene.name}: {', '.join(techniques)}", "",
             f"{frames} frames at {res[0]}x{res[1]}, budget {budget}, seed {seed}, "
             f"{info['variant']} (Mitsuba {info['mitsuba']}). Errors against Mitsuba's `path` integrator "
             "(cached ground truth); lower is better except SSIM. |E| and |E'|: SMC-IR Sec. 5.2 temporal "
             "error and its frame-to-frame change (flicker) after Reinhard tone mapping. ms/frame and "
             "Mrays/frame: means over the frames after the first (its kernel compilation and probe warm-up "
             "excluded).", "",
             "| technique | " + " | ".join(LABELS.get(k, k) for k in names) +
             " | abs(E) | abs(E') | ms/frame | Mrays/frame |",
             "|---|" + "---|" * (len(names) + 4)]
    best = {k: min(summary[t]["mean"][k] for t in techniques) for k in names if k != "ssim"}
    for t in techniques:
        s = summary[t]
        cells = []
        for k in names:
            v = f"{s['mean'][k]:.4g}"
            cells.append(f"**{v}**" if k != "ssim" and len(techniques) > 1 and s["mean"][k] == best[k] else v)
        lines.append(f"| {t} | " + " | ".join(cells) +
                     f" | {s['E']:.4g} | {s['E_prime']:.4g} | {s['ms_per_frame']:.1f} | "
                     f"{s['rays_per_frame'] / 1e6:.3g} |")
    if budget != "equal-frames":
        first = techniques[0]
        what = ("rays per frame" if budget == "equal-rays" else "median steady frame time "
                f"({summary[first]['ms_per_frame']:.1f} ms)")
        honour = [t for t in techniques[1:] if budget in get_technique(t).BUDGETS]
        ignore = [t for t in techniques[1:] if budget not in get_technique(t).BUDGETS]
        lines += ["", f"Budget: every technique gets the {what} of `{first}`"
                  + (f"; adapted by {', '.join(honour)}" if honour else "")
                  + (f"; {', '.join(ignore)} cannot adapt and ran its own settings" if ignore else "") + "."]
    lines += ["", _verdict(techniques, summary, names)]
    lines += ["", "## Milliseconds per frame by stage (steady state)", ""]
    for t in techniques:
        st = ", ".join(f"{k} {v:.1f}" for k, v in summary[t]["stage_ms"].items())
        lines.append(f"* **{t}**: {st}")
    return "\n".join(lines) + "\n"


def _verdict(techniques, summary, names) -> str:
    """One sentence on who wins on error and at what cost."""
    m = "relmse" if "relmse" in names else names[0]
    if m == "ssim" or len(techniques) < 2:
        return ""
    lab = LABELS.get(m, m)
    best = min(techniques, key=lambda t: summary[t]["mean"][m])
    fast = min(techniques, key=lambda t: summary[t]["ms_per_frame"])
    b, f = summary[best], summary[fast]
    if best == fast:
        return f"**Verdict:** `{best}` has the lowest {lab} and is also the fastest."
    ratio_e = f["mean"][m] / max(b["mean"][m], 1e-30)
    ratio_t = b["ms_per_frame"] / max(f["ms_per_frame"], 1e-9)
    return (f"**Verdict:** `{best}` has the lowest {lab}, {ratio_e:.2g}x lower than the fastest technique "
            f"`{fast}`, at {ratio_t:.2g}x its frame time. Compare at equal cost with `--budget equal-time`.")


def _plots(tmp, rows, techniques, summary, names):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    os.makedirs(os.path.join(tmp, "plots"), exist_ok=True)
    paths = []
    m0 = "relmse" if "relmse" in names else names[0]
    m1 = "flip" if "flip" in names else (names[1] if len(names) > 1 else names[0])
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    for t in techniques:
        r = [x for x in rows if x["technique"] == t]
        fr = [x["frame"] for x in r]
        axes[0].semilogy(fr, [max(x[m0], 1e-8) for x in r], label=t)
        axes[1].plot(fr, [x[m1] for x in r], label=t)
        wall = np.array([x["wall_ms"] for x in r], np.float64)
        if len(wall) > 1:   # frame 0 includes kernel compilation: count it as a steady frame
            wall[0] = np.median(wall[1:])
        axes[2].semilogy(np.cumsum(wall) / 1e3, [max(x[m0], 1e-8) for x in r], label=t)
    axes[0].set(xlabel="frame", ylabel=LABELS.get(m0, m0), title="error vs frame")
    axes[1].set(xlabel="frame", ylabel=LABELS.get(m1, m1), title=f"{LABELS.get(m1, m1)} vs frame")
    axes[2].set(xlabel="cumulative wall time (s; compile time excluded)", ylabel=LABELS.get(m0, m0),
                title="error vs wall time")
    for a in axes:
        a.legend()
        a.grid(alpha=0.3)
    fig.tight_layout()
    p = os.path.join(tmp, "plots", "errors.png")
    fig.savefig(p, dpi=90)
    plt.close(fig)
    paths.append(p)

    fig, ax = plt.subplots(figsize=(8.5, 1.2 + 0.5 * len(techniques)))
    stages = []
    for t in techniques:
        for k in summary[t]["stage_ms"]:
            if k not in stages:
                stages.append(k)
    left = np.zeros(len(techniques))
    for k in stages:
        vals = np.array([summary[t]["stage_ms"].get(k, 0.0) for t in techniques])
        ax.barh(techniques, vals, left=left, label=k)
        left += vals
    ax.set(xlabel="ms per frame", title="time per stage")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    p = os.path.join(tmp, "plots", "stages.png")
    fig.savefig(p, dpi=90)
    plt.close(fig)
    paths.append(p)
    return paths


def _grid(tmp, i, results, refs, flip):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(results)
    fig, axes = plt.subplots(len(names), 3, figsize=(9, 2.6 * len(names)), squeeze=False)
    for r, name in enumerate(names):
        img = np.maximum(np.nan_to_num(results[name].images[i]), 0.0)
        fmean, fmap = flip(img, refs[i], return_map=True)
        axes[r, 0].imshow(tonemap_srgb(img))
        axes[r, 0].set_title(f"{name}")
        axes[r, 1].imshow(tonemap_srgb(refs[i]))
        axes[r, 1].set_title("reference")
        axes[r, 2].imshow(fmap, cmap="magma", vmin=0, vmax=1)
        axes[r, 2].set_title(f"FLIP {fmean:.3f}")
        for a in axes[r]:
            a.axis("off")
    fig.suptitle(f"frame {i}")
    fig.tight_layout()
    p = os.path.join(tmp, f"grid_{i:04d}.png")
    fig.savefig(p, dpi=90)
    plt.close(fig)
    return p


def _label(img8: np.ndarray, text: str) -> np.ndarray:
    from PIL import Image, ImageDraw

    im = Image.fromarray(img8)
    d = ImageDraw.Draw(im)
    d.rectangle([0, 0, 7 * len(text) + 6, 14], fill=(0, 0, 0))
    d.text((3, 2), text, fill=(255, 255, 255))
    return np.asarray(im)


def _side_by_side(path, results, refs, fps):
    frames = []
    for i in range(len(refs)):
        tiles = [_label(tonemap_srgb(refs[i]), "reference")]
        tiles += [_label(tonemap_srgb(seq.images[i]), name) for name, seq in results.items()]
        frames.append(np.concatenate(tiles, axis=1))
    write_mp4(path, frames, fps=fps)


def _b64(path, mime):
    with open(path, "rb") as f:
        return f"data:{mime};base64," + base64.b64encode(f.read()).decode()


def _md_table_to_html(md: str) -> str:
    out, in_table = [], False
    for line in md.splitlines():
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            if all(set(c) <= set("-") for c in cells):
                continue
            tag = "th" if not in_table else "td"
            if not in_table:
                out.append("<table>")
                in_table = True
            out.append("<tr>" + "".join(f"<{tag}>{html.escape(c).replace('**', '')}</{tag}>" for c in cells) + "</tr>")
        else:
            if in_table:
                out.append("</table>")
                in_table = False
            if line.startswith("# "):
                out.append(f"<h1>{html.escape(line[2:])}</h1>")
            elif line.startswith("## "):
                out.append(f"<h2>{html.escape(line[3:])}</h2>")
            elif line.startswith("* "):
                out.append(f"<p>{html.escape(line[2:]).replace('**', '')}</p>")
            elif line.strip():
                out.append(f"<p>{html.escape(line).replace('**', '').replace('`', '')}</p>")
    if in_table:
        out.append("</table>")
    return "\n".join(out)


def _report_html(tmp, scene, md, plots, grids, video):
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>dyngi compare: "
             f"{html.escape(scene.name)}</title><style>body{{font-family:sans-serif;max-width:1200px;margin:auto}}"
             "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}"
             "img{max-width:100%}</style></head><body>", _md_table_to_html(md)]
    if scene.description:
        parts.append(f"<p><i>Scene:</i> {html.escape(scene.description)}"
                     + (f" (stands for {html.escape(scene.stands_for)})" if scene.stands_for else "") + "</p>")
    parts.append("<h2>Errors and timing</h2>")
    parts += [f"<img src='{_b64(p, 'image/png')}'>" for p in plots]
    parts.append("<h2>Images and FLIP error maps</h2>")
    parts += [f"<img src='{_b64(p, 'image/png')}'>" for p in grids]
    if video:
        vp = os.path.join(tmp, "side_by_side.mp4")
        if os.path.getsize(vp) < 30 * 1024 * 1024:
            parts.append(f"<h2>Side by side</h2><video controls loop src='{_b64(vp, 'video/mp4')}'></video>")
        else:
            parts.append("<h2>Side by side</h2><video controls loop src='side_by_side.mp4'></video>")
    parts.append("</body></html>")
    with open(os.path.join(tmp, "report.html"), "w") as f:
        f.write("\n".join(parts))
