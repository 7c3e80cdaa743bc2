"""Table 1 / Table 2 of the SMC-IR reproduction as Markdown, from the (sequence, seed) runs finished so far.

Reads ``OUT/SEQ/seedN/figures.json`` (:func:`dyngi.experiments.reproductions.smcir.run_pair`, written by
``dyngi reproduce smcir --out OUT``, whole or ``--only SEQ:SEEDS``), whatever seeds each sequence has, and
gives per sequence |E| and |E'| of the 8 tracked pixels (mean [min-max] over its seeds) for every
technique row beside the paper's Table 1 (after Reinhard tone mapping at the key of the image reference
sequence), the brightness-normalised |E| and |E'| (each estimate over its brightness) and the tracked reference's
own |E|, |E'| floor (from its two independent halves), the brightness (mean indirect / the reference's), the steady ms
per frame, smcir's |E'| rank per seed with the reproduction's stability verdict (one seed: not judged),
each run's wall time, and smcir's stage ms (Table 2). ``dyngi reproduce smcir --out OUT --table`` prints it;
docs/techniques/smcir.md records it.
"""
from __future__ import annotations

import glob
import json
import os

import numpy as np

from .smcir import METHODS, SEQUENCES, TABLE1, TABLE2, TABLE2_STAGES, ranking


def load_runs(out: str) -> dict:
    """``{sequence: [(seed, figures, wall_s), ...]}`` of the finished (sequence, seed) runs under ``out``, sorted by
    seed."""
    runs = {}
    for p in sorted(glob.glob(os.path.join(out, "*", "seed*", "figures.json"))):
        with open(p) as f:
            d = json.load(f)
        runs.setdefault(d["key"]["scene"], []).append((d["key"]["seed"], d["figures"], d["wall_s"]))
    return {k: sorted(v) for k, v in runs.items()}


def table_markdown(out: str) -> str:
    """Table 1 and Table 2 as Markdown from the runs finished under ``out`` (empty string: none yet)."""
    runs = load_runs(out)
    if not runs:
        return ""
    lines = []
    print = lines.append          # noqa: A001  (the rows below are written as lines)
    specs = list(next(iter(runs.values()))[0][1])
    labels = [next(s for s in specs if s.split(":")[0] == m) for m in METHODS]
    order = labels + [s for s in specs if s not in labels]
    print("| sequence (seeds) | quantity | " + " | ".join(f"`{s}`" for s in order)
          + " | paper (mir / ir / tcas / smcir) | smcir |E'| rank per seed; verdict |")
    print("|---" * (len(order) + 4) + "|")
    stage_rows = []
    for scene, _ in SEQUENCES:
        if scene not in runs:
            continue
        rr = runs[scene]
        figs = [f for _, f, _ in rr]
        seeds = [s for s, _, _ in rr]

        def cell(lab, key, fmt="{:.4f}"):
            v = np.array([f[lab].get(key, np.nan) for f in figs], np.float64)
            m = fmt.format(v.mean())
            return m if len(v) == 1 else f"{m} [{fmt.format(v.min())}-{fmt.format(v.max())}]"

        pe, pd = TABLE1[scene]
        me = {lab: np.mean([f[lab]["E_tracked"] for f in figs]) for lab in order}
        best = min(me[l] for l in labels if l != labels[3])
        verdict_e = f"smcir/best other {me[labels[3]] / best:.2f}x"
        for l in order:
            if l != labels[3] and l.startswith("smcir"):
                verdict_e += f" ({l.split(':', 1)[1]}: {me[l] / best:.2f}x)"
        rk = ranking(figs, specs)
        st = {True: "stable", False: "NOT stable", None: "one seed: not judged"}[rk["stable"]]
        ci = "" if len(figs) < 2 else f"; vs {rk['best_other']} {rk['diff_mean']:+.4f} [{rk['ci95'][0]:+.4f}, {rk['ci95'][1]:+.4f}]"
        verdict_d = f"{rk['ranks']}{ci}; {'lowest' if rk['lowest'] else 'not lowest'}, {st}"
        name = f"{scene} ({', '.join(map(str, seeds))})"
        print(f"| {name} | abs E | " + " | ".join(cell(l, "E_tracked") for l in order)
              + f" | {' / '.join(f'{v:.4f}' for v in pe)} | {verdict_e} |")
        print(f"| | abs E' | " + " | ".join(cell(l, "E_prime_tracked") for l in order)
              + f" | {' / '.join(f'{v:.4f}' for v in pd)} | {verdict_d} |")
        fl = [f[labels[3]].get("floor_E_prime_tracked", np.nan) for f in figs]
        fe = [f[labels[3]].get("floor_E_tracked", np.nan) for f in figs]
        spp = figs[0][labels[3]].get("tracked_spp", "?")
        print(f"| | abs E / brightness | " + " | ".join(cell(l, "E_tracked_norm") for l in order) + " | | |")
        print(f"| | abs E' / brightness | " + " | ".join(cell(l, "E_prime_tracked_norm") for l in order)
              + f" | | tracked reference's own floor: abs E {np.nanmean(fe) if np.isfinite(fe).any() else np.nan:.4f}, "
              f"abs E' {np.nanmean(fl) if np.isfinite(fl).any() else np.nan:.4f} ({spp} spp) |")
        print(f"| | brightness | " + " | ".join(cell(l, "brightness", "{:.2f}") for l in order) + " | | |")
        print(f"| | ms/frame (steady, mean) | " + " | ".join(f"{np.mean([f[l]['ms_per_frame'] for f in figs]):.0f}"
                                                         for l in order)
              + f" | | wall per seed {', '.join(f'{w / 60:.1f}' for _, _, w in rr)} min |")
        sm = [f[labels[3]]["stage_ms"] for f in figs]
        paper = {"corridor-walk": "Soda Hall", "street-canyon": "Epic Citadel", "maze": "Maze",
                 "atrium-sun": "Crytek Sponza", "street-canyon-moving-sun": "Epic Citadel"}[scene]
        stage_rows.append(f"| {scene} | " + " | ".join(f"{np.mean([s.get(k, 0.0) for s in sm]):.0f}" for k in TABLE2_STAGES)
                          + f" | {paper}: " + " / ".join(f"{v}" for v in TABLE2[paper]) + " |")
    print("")
    print("| sequence | " + " | ".join(TABLE2_STAGES) + " | paper (ms, GTX Titan X, 1920x1080) |")
    print("|---" * (len(TABLE2_STAGES) + 2) + "|")
    print("\n".join(stage_rows))
    return "\n".join(lines)

