"""Writing a comparison's outputs: metrics.csv, summary.md/.json, frames, plots, grids, video, report.html.

Used by ``dyngi compare`` and ``dyngi reproduce``; :func:`write_outputs` writes everything into a folder
(the caller makes it atomic). Techniques are labelled by their spec exactly as typed (``ddgi:hysteresis=0.9``)
in tables, plots, ``metrics.csv`` and ``summary.json``; per-technique frame folders use a file-name-safe
form of the label (:func:`folder_name`).
"""
from __future__ import annotations

import base64
import csv
import html
import os
import re

import numpy as np

from .. import backend
from ..metrics import flip
from ..techniques.base import get_technique
from .budgets import MAX_OVERSPEND
from .evaluate import LABELS, failures, noise_warning
from .io import tonemap_srgb, write_exr, write_json, write_mp4, write_png


def folder_name(label: str, taken=()) -> str:
    """A file-name-safe folder for a technique label (``ddgi:hysteresis=0.9`` -> ``ddgi_hysteresis=0.9``)."""
    base = re.sub(r"[^A-Za-z0-9_.=,+-]+", "_", label).strip("._") or "technique"
    name, k = base, 2
    while name in taken or name == "reference":
        name, k = f"{base}-{k}", k + 1
    return name


def write_outputs(tmp, scene, labels, specs, results, refs, rows, summary, ctx, names, grid_frames=None,
                  extra_md: str = "", title: str | None = None, extra_plots=()) -> str:
    """Write every output file of a comparison into ``tmp``; return the summary.md text.

    ``labels``: technique labels in order; ``specs``: label -> TechniqueSpec; ``results``: label ->
    SequenceResult; ``refs``: reference images; ``rows``/``summary``: from
    :func:`~dyngi.experiments.evaluate.evaluate_sequence`; ``ctx``: run settings (``frames``, ``res``,
    ``budget``, ``seed``, ``ref_spp``, ``ref_depth``, ``indirect``, ``ref_noise``, ``accounting``);
    ``extra_md``: appended to summary.md and the report (e.g. a paper's published figures);
    ``extra_plots``: more PNG paths (already in ``tmp``) embedded in the report.
    """
    frames = ctx["frames"]
    _write_csv(os.path.join(tmp, "metrics.csv"), rows)
    md = summary_md(scene, labels, specs, summary, ctx, names, title=title) + (("\n" + extra_md) if extra_md else "")
    with open(os.path.join(tmp, "summary.md"), "w") as f:
        f.write(md)
    write_json(os.path.join(tmp, "summary.json"), {
        "scene": scene.name, "frames": frames, "res": list(ctx["res"]), "budget": ctx["budget"],
        "seed": ctx["seed"], "ref_spp": ctx.get("ref_spp"), "ref_depth": ctx.get("ref_depth"),
        "indirect": bool(ctx.get("indirect")), "reference_noise": ctx.get("ref_noise"),
        "device": backend.device_info(),
        "techniques": {t: dict(summary[t], technique=specs[t].name, params=specs[t].params,
                               budget_accounting=(ctx.get("accounting") or {}).get(t)) for t in labels}})
    images = {t: _shown(results[t], ctx) for t in labels}
    taken = []
    for t in labels:
        d = folder_name(t, taken)
        taken.append(d)
        os.makedirs(os.path.join(tmp, d), exist_ok=True)
        for i, img in enumerate(images[t]):
            write_png(os.path.join(tmp, d, f"frame_{i:04d}.png"), img)
            write_exr(os.path.join(tmp, d, f"frame_{i:04d}.exr"), img)
    os.makedirs(os.path.join(tmp, "reference"), exist_ok=True)
    for i, r in enumerate(refs):
        write_png(os.path.join(tmp, "reference", f"frame_{i:04d}.png"), r)
    plots = _plots(tmp, rows, labels, summary, names) + list(extra_plots)
    gframes = grid_frames if grid_frames is not None else sorted({frames // 2, frames - 1})
    grids = [_grid(tmp, i, images, refs, flip) for i in gframes if 0 <= i < frames]
    if frames > 1:
        _side_by_side(os.path.join(tmp, "side_by_side.mp4"), images, refs, scene.fps)
    _report_html(tmp, scene, md, plots, grids, frames > 1)
    return md


def _shown(seq, ctx):
    return seq.indirect if ctx.get("indirect") else seq.images


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


def summary_md(scene, techniques, specs, summary, ctx, names, title: str | None = None) -> str:
    """The summary.md text: table per technique, reference noise, budget accounting, failures, verdict."""
    info = backend.device_info()
    frames, res, budget, seed = ctx["frames"], ctx["res"], ctx["budget"], ctx["seed"]
    if ctx.get("indirect"):
        what, truth = "indirect-only images", "dyngi's `path` tracer in its indirect-only mode (validated against Mitsuba)"
    else:
        what, truth = "images", "Mitsuba's `path` integrator"
    lines = [f"# {title or scene.name}: {', '.join(techniques)}", "",
             f"{frames} frames at {res[0]}x{res[1]}, budget {budget}, seed {seed}, "
             f"{info['variant']} (Mitsuba {info['mitsuba']}). Errors of the {what} against {truth} "
             f"at {ctx.get('ref_spp')} spp, max depth {ctx.get('ref_depth')} "
             "(cached ground truth); lower is better except SSIM. |E| and |E'|: SMC-IR Sec. 5.2 temporal "
             "error and its frame-to-frame change (flicker) after Reinhard tone mapping, over every pixel "
             "against the image reference, and (8px) over the 8 tracked pixels against their own per-pixel "
             "reference of more samples (summary.json: E_tracked, E_prime_tracked, tracked_pixels, tracked_spp; "
             "one pixel per cell of a 4x2 grid, the cell's median lit pixel of frame 0's reference). ms/frame and "
             "Mrays/frame: means over the frames after the first (its kernel compilation and probe warm-up "
             "excluded).", "",
             "| technique | " + " | ".join(LABELS.get(k, k) for k in names) +
             " | abs(E) | abs(E') | abs(E) 8px | abs(E') 8px | ms/frame | Mrays/frame | NaN/Inf px |",
             "|---|" + "---|" * (len(names) + 7)]
    ok = [t for t in techniques if not summary[t].get("failed")]
    best = {k: min(summary[t]["mean"][k] for t in ok) for k in names if k != "ssim"} if ok else {}
    for t in techniques:
        s = summary[t]
        cells = []
        for k in names:
            v = f"{s['mean'][k]:.4g}"
            cells.append(f"**{v}**" if k in best and len(techniques) > 1 and s["mean"][k] == best[k] else v)
        bad = f"**FAILED: {s['nonfinite_pixels']}**" if s.get("failed") else "0"
        lines.append(f"| {t} | " + " | ".join(cells) +
                     f" | {s['E']:.4g} | {s['E_prime']:.4g} | {s.get('E_tracked', float('nan')):.4g} | "
                     f"{s.get('E_prime_tracked', float('nan')):.4g} | {s['ms_per_frame']:.1f} | "
                     f"{s['rays_per_frame'] / 1e6:.3g} | {bad} |")
    fails = failures(summary)
    if fails:
        lines += ["", "**FAILED** (NaN/Inf pixels; the metrics of those frames are NaN, nothing was zeroed): "
                  + "; ".join(fails) + "."]
    neg = [f"{t} ({summary[t]['negative_pixels']})" for t in techniques if summary[t].get("negative_pixels")]
    if neg:
        lines += ["", "Negative pixels (enter MSE/relMSE/MAPE as they are, FLIP/SSIM/|E| as 0): "
                  + ", ".join(neg) + "."]
    for w in ctx.get("warnings", []):
        lines += ["", f"**Warning:** {w}."]
    for n in ctx.get("notes", []):
        lines += ["", n]
    rn = ctx.get("ref_noise") or {}
    if rn:
        lines += ["", f"Reference noise (two independent halves): relMSE {rn.get('relmse', float('nan')):.3g}, "
                  f"MSE {rn.get('mse', float('nan')):.3g} (mean over frames)."]
        warn = noise_warning(summary, rn, names)
        if warn:
            lines += ["", f"**Warning:** {warn}."]
    if budget != "equal-frames":
        first = techniques[0]
        what = ("rays per frame" if budget == "equal-rays" else "median steady frame time "
                f"({summary[first]['ms_per_frame']:.1f} ms)")
        honour = [t for t in techniques[1:] if budget in get_technique(specs[t].name).BUDGETS]
        ignore = [t for t in techniques[1:] if budget not in get_technique(specs[t].name).BUDGETS]
        lines += ["", f"Budget: every technique gets the {what} of `{first}`"
                  + (f"; adapted by {', '.join(honour)}" if honour else "")
                  + (f"; {', '.join(ignore)} cannot adapt and ran its own settings" if ignore else "") + "."]
        acc = ctx.get("accounting") or {}
        if any(acc.get(t) for t in techniques[1:]):
            unit = "rays" if budget == "equal-rays" else "wall time"
            lines += ["", f"| technique | {unit} spent / budget: {'every frame from 0' if budget == 'equal-rays' else 'all frames'} | steady max frame | "
                      + ("steady median | " if budget == "equal-time" else "") + "frame 0 | within 5% |",
                      "|---|---|---|" + ("---|" if budget == "equal-time" else "") + "---|---|"]
            for t in techniques[1:]:
                a = acc.get(t)
                if not a:
                    continue
                med = f" {a['steady_median_ratio']:.3f} |" if budget == "equal-time" else ""
                lines.append(f"| {t} | {a['total_ratio']:.3f} | {a['steady_max_ratio']:.3f} |{med} "
                             f"{a['frame0_ratio']:.3f} | {'no' if a['overspent'] else 'yes'} |")
            lines += ["", f"Rule: no technique spends more than {100 * MAX_OVERSPEND:.0f}% over its budget "
                      "(equal rays: over every frame from frame 0, warm-up and pilot included, a step over the "
                      "budget on one frame repaid on the next; equal time: the median steady frame, wall time on "
                      "a shared CPU is noisy, frame 0 holding the kernel compilation)."]
    lines += ["", verdict(techniques, summary, names)]
    lines += ["", "## Milliseconds per frame by stage (steady state)", ""]
    for t in techniques:
        st = ", ".join(f"{k} {v:.1f}" for k, v in summary[t]["stage_ms"].items())
        lines.append(f"* **{t}**: {st}")
    work = {t: probe_work_ms(summary[t]["stage_ms"]) for t in techniques}
    if sum(v is not None for v in work.values()) >= 1:
        lines += ["", "| technique | total probe work (ms per frame: every stage but primary shading) |", "|---|---|"]
        lines += [f"| {t} | {v:.1f} |" for t, v in work.items() if v is not None]
    return "\n".join(lines) + "\n"


PRIMARY_STAGES = ("primary",)
"""The stages of a probe technique's frame that shade the image (the deferred pass); every other stage is probe
work (ADGI's P + S + D and its merges, Q-DDGI's trace, shade, blend and states, a warm-up)."""


def probe_work_ms(stage_ms: dict) -> float | None:
    """A probe technique's probe work in ms: the sum of its stages but primary shading (ADGI's Table 4 "probe
    sampling" against Q-DDGI's); None for a technique without a primary stage (no probe volume)."""
    if not any(k in stage_ms for k in PRIMARY_STAGES):
        return None
    return float(sum(v for k, v in stage_ms.items() if k not in PRIMARY_STAGES))


def verdict(techniques, summary, names) -> str:
    """One sentence on who wins on error and at what cost."""
    m = "relmse" if "relmse" in names else names[0]
    techniques = [t for t in techniques if not summary[t].get("failed")]
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
        axes[0].semilogy(fr, [max(x[m0], 1e-8) if np.isfinite(x[m0]) else np.nan for x in r], label=t)
        axes[1].plot(fr, [x[m1] for x in r], label=t)
        wall = np.array([x["wall_ms"] for x in r], np.float64)
        if len(wall) > 1:   # frame 0 includes kernel compilation: count it as a steady frame
            wall[0] = np.median(wall[1:])
        axes[2].semilogy(np.cumsum(wall) / 1e3, [max(x[m0], 1e-8) if np.isfinite(x[m0]) else np.nan for x in r],
                         label=t)
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


def _grid(tmp, i, images, refs, flip):
    """Image grid of frame ``i``: technique, reference, FLIP map (a failed frame shows no FLIP map)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(images)
    # constrained layout keeps each row's titles clear of the images above (tight_layout with a suptitle
    # let them overlap); the row height follows the image's aspect, plus room for the titles
    h, w = np.asarray(refs[i]).shape[:2]
    fig, axes = plt.subplots(len(names), 3, figsize=(9, (2.9 * h / w + 0.45) * len(names) + 0.35), squeeze=False,
                             layout="constrained")
    for r, name in enumerate(names):
        img = np.asarray(images[name][i])
        if np.all(np.isfinite(img)):
            fmean, fmap = flip(np.maximum(img, 0.0), refs[i], return_map=True)
            ftitle = f"FLIP {fmean:.3f}"
        else:   # shown, not measured: NaN/Inf pixels in magenta -- a failure
            fmap = np.zeros(img.shape[:2], np.float32)
            ftitle = f"FAILED: {int((~np.isfinite(img)).any(axis=-1).sum())} NaN/Inf px"
        axes[r, 0].imshow(_shown_srgb(img))
        axes[r, 0].set_title(f"{name}")
        axes[r, 1].imshow(tonemap_srgb(refs[i]))
        axes[r, 1].set_title("reference")
        axes[r, 2].imshow(fmap, cmap="magma", vmin=0, vmax=1)
        axes[r, 2].set_title(ftitle)
        for a in axes[r]:
            a.axis("off")
    fig.suptitle(f"frame {i}")
    p = os.path.join(tmp, f"grid_{i:04d}.png")
    fig.savefig(p, dpi=90)
    plt.close(fig)
    return p


def _shown_srgb(img) -> np.ndarray:
    """8-bit sRGB for display, with NaN/Inf pixels in magenta (not hidden as black)."""
    out = np.array(tonemap_srgb(img), copy=True)
    bad = ~np.isfinite(np.asarray(img)).all(axis=-1)
    if bad.any():
        out[bad] = (255, 0, 255)
    return out


def _label(img8: np.ndarray, text: str) -> np.ndarray:
    from PIL import Image, ImageDraw

    im = Image.fromarray(img8)
    d = ImageDraw.Draw(im)
    d.rectangle([0, 0, 7 * len(text) + 6, 14], fill=(0, 0, 0))
    d.text((3, 2), text, fill=(255, 255, 255))
    return np.asarray(im)


def _side_by_side(path, images, refs, fps):
    frames = []
    for i in range(len(refs)):
        tiles = [_label(tonemap_srgb(refs[i]), "reference")]
        tiles += [_label(_shown_srgb(imgs[i]), name) for name, imgs in images.items()]
        frames.append(np.concatenate(tiles, axis=1))
    write_mp4(path, frames, fps=fps)


def data_uri(path: str, mime: str) -> str:
    """The file at ``path`` as a ``data:`` URI (reports embed their images, so one file is the report)."""
    with open(path, "rb") as f:
        return f"data:{mime};base64," + base64.b64encode(f.read()).decode()


def md_to_html(md: str) -> str:
    """The subset of Markdown our summaries use (headings, bullets, paragraphs, pipe tables) as HTML."""
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
             "img{max-width:100%}</style></head><body>", md_to_html(md)]
    if scene.description:
        parts.append(f"<p><i>Scene:</i> {html.escape(scene.description)}"
                     + (f" (stands for {html.escape(scene.stands_for)})" if scene.stands_for else "") + "</p>")
    parts.append("<h2>Errors and timing</h2>")
    parts += [f"<img src='{data_uri(p, 'image/png')}'>" for p in plots]
    parts.append("<h2>Images and FLIP error maps</h2>")
    parts += [f"<img src='{data_uri(p, 'image/png')}'>" for p in grids]
    if video:
        vp = os.path.join(tmp, "side_by_side.mp4")
        if os.path.getsize(vp) < 30 * 1024 * 1024:
            parts.append(f"<h2>Side by side</h2><video controls loop src='{data_uri(vp, 'video/mp4')}'></video>")
        else:
            parts.append("<h2>Side by side</h2><video controls loop src='side_by_side.mp4'></video>")
    parts.append("</body></html>")
    with open(os.path.join(tmp, "report.html"), "w") as f:
        f.write("\n".join(parts))


def scaling_plot(rows: list, path: str, title: str = "probe work against grid size") -> str:
    """The scaling curve (ADGI's Table 4 claim, Sec. 7: sampling "decoupled from the number of probes"): per
    technique, probe-work ms per frame (:func:`probe_work_ms`) against the probe count, log-log. ``rows``:
    dicts with ``technique``, ``probes``, ``probe_ms`` (and optionally ``probe_ms_lo`` / ``probe_ms_hi``, drawn
    as a band). Writes ``path`` (PNG) and returns it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.0, 3.6))
    for t in dict.fromkeys(r["technique"] for r in rows):
        rr = sorted((r for r in rows if r["technique"] == t), key=lambda r: r["probes"])
        x = [r["probes"] for r in rr]
        ax.loglog(x, [r["probe_ms"] for r in rr], marker="o", label=t)
        if all("probe_ms_lo" in r for r in rr):
            ax.fill_between(x, [r["probe_ms_lo"] for r in rr], [r["probe_ms_hi"] for r in rr], alpha=0.2)
    ax.set(xlabel="probes", ylabel="probe work, ms per frame", title=title)
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
