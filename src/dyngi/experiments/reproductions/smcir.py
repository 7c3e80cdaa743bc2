"""``dyngi reproduce smcir``: Table 1 (and Table 2's stage breakdown) of Hedman, Karras, Lehtinen,
"Sequential Monte Carlo Instant Radiosity", IEEE TVCG 2017, on our five analog sequences.

Sequences (Table 1 row: our analog): Soda Hall, 14 static lights: ``corridor-walk``; Epic Citadel,
static sun: ``street-canyon``; Maze, 13 static lights (512 VPLs): ``maze``; Crytek Sponza, one moving
light: ``atrium-sun``; Epic Citadel, moving sun: ``street-canyon-moving-sun``. Techniques ``mir``,
``ir``, ``tcas``, ``smcir`` at the same VPL budget (the scene's: 2048, 512 for the maze), the same
visibility (ray-traced: our substitution for the paper's 128x128 paraboloid shadow maps), the same 4x4
interleaving and cross-bilateral filter; equal VPL budget, not equal time (as the paper, Sec. 5.3).

Measured as Sec. 5.2: indirect light only (``--indirect``) against the path-traced indirect reference
with the same three bounces (max depth 5); |E| and |E'| (Eq. 10) after Reinhard tone mapping over the
8 tracked pixels (:func:`dyngi.metrics.temporal.pick_tracked_pixels`) against their per-pixel
reference of 16x the image reference's samples (``E_tracked`` / ``E_prime_tracked`` in each
``summary.json``), and over all pixels against the image reference. Our sequences are shorter (6 s
instead of 20-30 s) and our images smaller; the paper's numbers are beside ours for the ranking, not
for the values. Also ``smcir:density_k=16``: Eq. 8's k = 1 over-estimates 1/p on the blue-noise-like
VPL set that replacements produce (tests/techniques/test_smcir.py), so the table shows what a larger k changes.
``--quick``: two sequences, 4 frames at 32x24, few warm-up iterations (well under 3 minutes).
``--reference clamped`` (Sec. 5.4), ``--untextured`` (Sec. 5) and ``--no-tracked`` reach every sequence.

Measured (96x54, 30 frames, mir 64:1, 2-core CPU; the full config's 60 frames and mir 256:1 took too long):
smcir lowest |E'| on 4 of 5 sequences (not the maze: ir, tcas lower); its |E| within 1.2x of mir's only on
the moving-sun street (1.12), the atrium 4.8x as in the paper's own row; most of the gap is Eq. 8's k = 1
density bias (``smcir:density_k=16`` closes part of it), see :mod:`dyngi.techniques.smcir`.
"""
from __future__ import annotations

import os

import numpy as np

from ..io import atomic_output_dir
from ..reproduce import paper_table, register_experiment
from ._summary import write_summary

PAPER = ("Hedman, Karras, Lehtinen, \"Sequential Monte Carlo Instant Radiosity\", IEEE TVCG 23(5), 2017 "
         "(extends I3D 2016)")
SEQUENCES = (("corridor-walk", "Soda Hall, 14 static lights"), ("street-canyon", "Epic Citadel, static light"),
             ("maze", "Maze, 13 static lights"), ("atrium-sun", "Crytek Sponza, dynamic light"),
             ("street-canyon-moving-sun", "Epic Citadel, dynamic light"))
METHODS = ("mir", "ir", "tcas", "smcir")
TABLE1 = {   # Table 1: (|E| MIR, IR, TCAS, Ours), (|E'| MIR, IR, TCAS, Ours)
    "corridor-walk": ((0.0262, 0.0551, 0.0526, 0.0206), (0.0098, 0.0077, 0.0057, 0.0044)),
    "street-canyon": ((0.0492, 0.0827, 0.0626, 0.0473), (0.0241, 0.0364, 0.0227, 0.0222)),
    "maze": ((0.0287, 0.0869, 0.0380, 0.0221), (0.0216, 0.0132, 0.0113, 0.0075)),
    "atrium-sun": ((0.0288, 0.0215, 0.0352, 0.0962), (0.0072, 0.0044, 0.0027, 0.0014)),
    "street-canyon-moving-sun": ((0.0246, 0.0892, 0.0650, 0.0240), (0.0129, 0.0323, 0.0198, 0.0071)),
}
TABLE2_STAGES = {"candidates": "Cand. sampling", "resampling": "Cand. resampling",
                 "visibility": "Indirect visibility", "radiosity": "Radiosity", "knn": "kNN",
                 "shading": "Interl. shading (incl. G-buffer, direct light)"}
TABLE2 = {"Soda Hall": (2.3, 2.2, 1.2, 7.8, 1.7, 19.1), "Epic Citadel": (3.3, 3.0, 1.6, 11.0, 2.6, 20.0),
          "Crytek Sponza": (2.7, 2.5, 2.0, 9.8, 1.6, 24.4), "Maze": (2.2, 1.6, 1.1, 6.8, 1.6, 10.5)}
SMCIR_QUICK = {"scenes": ("maze", "corridor-walk"), "res": (32, 24), "frames": 4, "ref_spp": 32,
               "specs": ("mir:resampling_rate=16", "ir", "tcas:iterations=4", "smcir:warmup=5",
                         "smcir:warmup=5:density_k=16")}
SMCIR_FULL = {"scenes": tuple(s for s, _ in SEQUENCES), "res": (96, 54), "frames": 60, "ref_spp": 256,
              "specs": ("mir", "ir", "tcas", "smcir", "smcir:density_k=16")}


def run_scene(scene_name: str, cfg: dict, out_dir: str, quiet: bool = True, reference: str = "path",
              untextured: bool = False, tracked: bool = True) -> dict:
    """All methods on one sequence, the usual report in ``out_dir``; returns their summaries."""
    from ..compare import execute, prepare
    from ..report import write_outputs

    run = prepare(scene_name, list(cfg["specs"]), out_dir, cfg["frames"], "equal-frames", cfg["ref_spp"], {},
                  ["mse", "relmse"], 5, True, reference=reference, untextured=untextured, tracked=tracked)
    rs = execute(run, cfg["res"], seed=0, quiet=quiet)
    with atomic_output_dir(out_dir) as tmp:
        write_outputs(tmp, run["scene"], run["labels"], run["specs"], rs["results"], rs["refs"], rs["rows"],
                      rs["summary"], rs["ctx"], run["names"], title=f"reproduce smcir ({scene_name})")
    out = {}
    for label, s in rs["summary"].items():
        seq = rs["results"][label]
        steady, _ = seq.steady()
        used = [st.get("vpls_used") for st in steady if st.get("vpls_used") is not None]
        out[label] = {"E": s["E"], "E_prime": s["E_prime"], "E_tracked": s["E_tracked"],
                      "E_prime_tracked": s["E_prime_tracked"], "relmse": s["mean"]["relmse"],
                      "ms_per_frame": s["ms_per_frame"], "stage_ms": s["stage_ms"],
                      "vpls_used": float(np.mean(used)) if used else None,
                      "vpl_budget": steady[0].get("vpl_budget") if steady else None,
                      "tracked_pixels": s.get("tracked_pixels"), "failed": bool(s.get("failed")),
                      "nonfinite_pixels": int(s.get("nonfinite_pixels", 0)),
                      "nonfinite_frames": int(s.get("nonfinite_frames", 0))}
    return out


def _method_label(specs, method):
    return next(s for s in specs if s.split(":")[0] == method)


def _rows(figs: dict, cfg: dict) -> list:
    rows = []
    for scene, what in SEQUENCES:
        if scene not in figs:
            continue
        f = figs[scene]
        pe, pd = TABLE1[scene]
        labels = [_method_label(cfg["specs"], m) for m in METHODS]
        ours_e = ", ".join(f"{m} {f[l]['E_tracked']:.4f}" for m, l in zip(METHODS, labels))
        ours_d = ", ".join(f"{m} {f[l]['E_prime_tracked']:.4f}" for m, l in zip(METHODS, labels))
        best_e = METHODS[int(np.nanargmin([f[l]["E_tracked"] for l in labels]))]
        best_d = METHODS[int(np.nanargmin([f[l]["E_prime_tracked"] for l in labels]))]
        rows.append((f"{scene} ({what}): |E|, 8 px",
                     ", ".join(f"{m} {v:.4f}" for m, v in zip(METHODS, pe)) + f"; lowest {METHODS[int(np.argmin(pe))]}",
                     ours_e + f"; lowest {best_e}"))
        rows.append((f"{scene}: |E'|, 8 px",
                     ", ".join(f"{m} {v:.4f}" for m, v in zip(METHODS, pd)) + f"; lowest {METHODS[int(np.argmin(pd))]}",
                     ours_d + f"; lowest {best_d}"))
        k16 = [s for s in cfg["specs"] if "density_k" in s]
        extra = "; ".join(f"{s}: |E| {f[s]['E_tracked']:.4f}, |E'| {f[s]['E_prime_tracked']:.4f}" for s in k16)
        rows.append((f"{scene}: all pixels |E| / |E'|; VPLs used (ir)", "no figure (the paper tracks 8 pixels)",
                     ", ".join(f"{m} {f[l]['E']:.4f}/{f[l]['E_prime']:.4f}" for m, l in zip(METHODS, labels))
                     + f"; ir used {f[labels[1]]['vpls_used']:.0f} of {f[labels[1]]['vpl_budget']} VPLs"
                     + (f"; {extra}" if extra else "")))
    # Table 2: per-stage ms of smcir
    for scene, _ in SEQUENCES:
        if scene not in figs:
            continue
        st = figs[scene][_method_label(cfg["specs"], "smcir")]["stage_ms"]
        paper = {"corridor-walk": "Soda Hall", "street-canyon": "Epic Citadel", "maze": "Maze",
                 "atrium-sun": "Crytek Sponza", "street-canyon-moving-sun": "Epic Citadel"}[scene]
        pv = TABLE2[paper]
        sampling = sum(st.get(k, 0.0) for k in ("candidates", "resampling", "visibility", "radiosity", "knn"))
        rows.append((f"{scene}: smcir ms per stage (Table 2, {paper})",
                     ", ".join(f"{TABLE2_STAGES[k]} {v}" for k, v in zip(TABLE2_STAGES, pv))
                     + f"; sampling total {sum(pv[:5]):.1f} (GTX Titan X, 1920x1080, shadow maps)",
                     ", ".join(f"{TABLE2_STAGES[k]} {st.get(k, 0.0):.1f}" for k in TABLE2_STAGES)
                     + f"; sampling total {sampling:.1f} (2-core CPU, {cfg['res'][0]}x{cfg['res'][1]}, ray-traced)"))
    return rows


@register_experiment("smcir", "SMC-IR Table 1 (|E|, |E'| of 8 tracked pixels: MIR, IR, TCAS, SMC-IR, equal VPL "
                     "budget) and Table 2 (stage ms) on five analog sequences", PAPER)
def reproduce_smcir(out_dir: str, quick: bool = False, quiet: bool = True, reference: str = "path",
                    untextured: bool = False, tracked: bool = True) -> str:
    """The ``smcir`` experiment (module docstring); ``quick``: :data:`SMCIR_QUICK`, else :data:`SMCIR_FULL`.

    ``reference``: ``'path'`` (the path-traced indirect reference, Sec. 5.2) or ``'clamped'`` (clamped
    path tracing, Sec. 5.4); ``untextured``: average albedos (Sec. 5); ``tracked=False``: no per-pixel
    tracked reference (the image reference's values stand in); the CLI's ``--reference``,
    ``--untextured``, ``--no-tracked``."""
    from ..clamped_reference import check_reference

    check_reference(reference, True)
    cfg = SMCIR_QUICK if quick else SMCIR_FULL
    figs = {sc: run_scene(sc, cfg, os.path.join(out_dir, sc), quiet, reference, untextured, tracked)
            for sc in cfg["scenes"]}
    rows = _rows(figs, cfg)
    ref_text = ("clamped path-traced (Sec. 5.4) indirect reference" if reference == "clamped" else
                "path-traced indirect reference") + (", untextured (average albedos)" if untextured else "")
    tr_text = "tracked pixels 16x that" if tracked else "tracked pixels read from the image reference"
    md = "\n".join([f"# reproduce smcir ({'quick' if quick else 'full'} run)", "", "SMC-IR: " + PAPER + ".",
                    f"Techniques {', '.join(cfg['specs'])}; {cfg['frames']} frames at {cfg['res'][0]}x{cfg['res'][1]}, "
                    f"indirect light only against the {ref_text} (max depth 5, "
                    f"{cfg['ref_spp']} spp; {tr_text}), equal VPL budget; per-sequence reports in "
                    "the sub-folders. Visibility is ray-traced (our substitution for 128x128 paraboloid shadow "
                    "maps).", "", paper_table(rows), ""])
    return write_summary(out_dir, md, {
        "paper.json": {"experiment": "smcir", "quick": quick, "paper": PAPER, "figures": figs,
                       "reference": reference, "untextured": bool(untextured), "tracked": bool(tracked),
                       "rows": [{"quantity": q, "paper": p, "ours": o} for q, p, o in rows]},
        # every run, as the CLI reads it
        "summary.json": {"experiment": "smcir", "techniques": {f"{sc}/{lab}": v for sc, d in figs.items()
                                                               for lab, v in d.items()}}})
