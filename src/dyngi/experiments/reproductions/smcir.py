"""``dyngi reproduce smcir``: Table 1 (and Table 2's stage breakdown) of Hedman, Karras, Lehtinen,
"Sequential Monte Carlo Instant Radiosity", IEEE TVCG 2017, on our five analog sequences.

Sequences (Table 1 row: our analog): Soda Hall, 14 static lights: ``corridor-walk``; Epic Citadel,
static sun: ``street-canyon``; Maze, 13 static lights (512 VPLs): ``maze``; Crytek Sponza, one moving
light: ``atrium-sun``; Epic Citadel, moving sun: ``street-canyon-moving-sun``. Techniques ``mir``,
``ir``, ``tcas``, ``smcir`` at the same VPL budget (the scene's: 2048, 512 for the maze), the same
visibility (ray-traced: our substitution for the paper's 128x128 paraboloid shadow maps), the same 4x4
interleaving and cross-bilateral filter; equal VPL budget, not equal time (as the paper, Sec. 5.3).

Measured as Sec. 5.2: indirect light only (``--indirect``) against the path-traced indirect reference
with the same three bounces (max depth 5); |E| and |E'| (Eq. 10) over the 8 tracked pixels
(:func:`dyngi.metrics.temporal.pick_tracked_pixels`) against their per-pixel reference (``E_tracked`` /
``E_prime_tracked`` in each ``figures.json``), and over all pixels against the image reference. The
tracked reference (:func:`tracked_measure`) has at least 65,536 samples per pixel (the paper: 692,100),
rendered as two independent halves whose difference gives its own |E|, |E'| -- the floor under every
method's, shown beside the table. Tone mapping: Reinhard's operator at the key value a / Lw of the image
reference sequence (Reinhard et al. 2002; ``exposure='auto'``, as the flicker test), not the harness's fixed
k = 1 (kept as ``*_k1``); ``E_prime_tracked_norm`` divides each estimate by its brightness first, so that a
dim method (``tcas``: one bounce) cannot flicker less by being dim. Every sequence runs with ``seeds`` (3)
technique seeds against one reference: each row gives the mean and the spread (min-max) over the seeds.

Claims (:func:`declare_claims`, decided by :mod:`dyngi.experiments.claims`): Table 1's |E'| -- smcir below
MIR, the paper's IR and TCAS on every sequence -- and its |E| -- below them on the four sequences where the
paper has it lowest (:data:`TABLE1_E_LOWEST`); the paper-literal row reads Eq. 8 as printed
(``smcir:eq8=text``). The paper's IR is ``ir:photons=qmc`` (quasi-random photons, a scrambled Sobol' set
per frame); ``ir`` (pseudo-random per frame), ``ir:photons=halton`` (Keller's deterministic Halton
prefixes) and ``ir:photons=fixed`` (one set for the sequence: a temporal-coherence device the paper's IR
lacks) are rows of their own. The older per-sequence ranking (:func:`ranking`: smcir's rank per seed and a
paired t interval) stays in the table beside the verdicts. Table 2's stage breakdown comes from smcir's
per-stage ms.

Each (sequence, seed) saves its figures in ``OUT/SEQ/seedN/figures.json`` as it ends and a later run
with the same settings reads them back (:func:`run_pair`): a full run can be resumed, or split over
processes (``dyngi reproduce smcir --only SEQ:SEEDS``) and gathered by one more ``dyngi reproduce smcir --out OUT``. The
references (image and tracked pixels) do not depend on the technique seed: they are rendered once per
sequence and frame and cached on disk (:mod:`dyngi.experiments.references.path`), so seeds 2 and 3 cost only the
techniques' frames.

The full configuration (:data:`SMCIR_FULL`, the command's default: five sequences, 160x90, 60 frames,
the paper's VPL counts, mir at 256:1, 3 seeds) is the issue-29 size; ``--quick``: two sequences, 4
frames at 32x24, one seed, few warm-up iterations. The Python API takes a ``config`` to run a scaled
version (what docs/techniques/smcir.md records when the full one does not fit a shared 2-core box).
Our sequences are shorter (6 s instead of 20-30 s) and our images smaller; the paper's numbers are
beside ours for the ranking, not for the values.
"""
from __future__ import annotations

import json
import os
import time

import numpy as np

from ...errors import DyngiError
from .. import cluster
from ..claims import Claim, Criterion, claim_rows, claims_json, result_from_values, verdict_table
from ..compare import execute, prepare
from ..evaluate import tracked_exposure, tracked_reference_floor, tracked_temporal
from ..io import atomic_output_dir
from ..references.clamped import check_reference
from ..references.tracked import (TRACKED_SPP_FACTOR, TRACKED_SPP_MAX, TRACKED_SPP_MIN_SMCIR,
                                  cached_tracked_halves)
from ...techniques.base import parse_spec
from ..report import write_outputs
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
TABLE1_E_LOWEST = ("corridor-walk", "street-canyon", "maze", "street-canyon-moving-sun")
"""The sequences on which Table 1 has smcir's |E| lowest of the four (4 of 5; Crytek Sponza: IR's)."""
SMCIR_QUICK = {"scenes": ("maze", "corridor-walk"), "res": (32, 24), "frames": 4, "ref_spp": 32, "seeds": (0,),
               "specs": ("mir:resampling_rate=16", "ir:photons=qmc", "ir", "ir:photons=fixed", "tcas:iterations=4",
                         "smcir:warmup=5", "smcir:warmup=5:eq8=text")}
SMCIR_FULL = {"scenes": tuple(s for s, _ in SEQUENCES), "res": (160, 90), "frames": 60, "ref_spp": 256,
              "seeds": (0, 1, 2), "specs": ("mir", "ir:photons=qmc", "ir", "ir:photons=halton", "ir:photons=fixed",
                                            "tcas", "smcir", "smcir:eq8=text")}
"""The first spec of each method is its Table 1 row (:func:`_method_label`): ``ir:photons=qmc`` is the
paper's IR (quasi-random photons, a scrambled Sobol' set per frame; ``ir:photons=halton``, Keller's
deterministic Halton points with a new prefix per frame, beside it: :mod:`dyngi.techniques.ir` says why);
``smcir:eq8=text`` is the paper-literal row of the claims (Eq. 8 as printed, k = 1)."""
MEASURE_VERSION = 2
"""What a saved figures.json measured (2: the tracked reference of >= 65,536 spp as two halves, Reinhard's key)."""
CONFIG_KEYS = ("scenes", "res", "frames", "ref_spp", "seeds", "specs")


def run_scene(scene_name: str, cfg: dict, out_dir: str, quiet: bool = True, reference: str = "path",
              untextured: bool = False, tracked: bool = True, seed: int = 0) -> dict:
    """All methods on one sequence with one technique seed, the usual report in ``out_dir``; returns
    their summaries (``brightness``: mean indirect / the reference's, over all frames)."""
    own = tracked and reference == "path"    # the tracked pixels' reference of >= 65,536 spp, rendered here
    run = prepare(scene_name, list(cfg["specs"]), out_dir, cfg["frames"], "equal-frames", cfg["ref_spp"], {},
                  ["mse", "relmse"], 5, True, reference=reference, untextured=untextured, tracked=tracked and not own)
    rs = execute(run, cfg["res"], seed=seed, quiet=quiet)
    tk = tracked_measure(run, rs, cfg, own)
    with atomic_output_dir(out_dir) as tmp:
        write_outputs(tmp, run["scene"], run["labels"], run["specs"], rs["results"], rs["refs"], rs["rows"],
                      rs["summary"], rs["ctx"], run["names"], title=f"reproduce smcir ({scene_name}, seed {seed})")
    ref_mean = float(np.mean([np.mean(r) for r in rs["refs"]]))
    out = {}
    for label, s in rs["summary"].items():
        seq = rs["results"][label]
        steady, _ = seq.steady()
        used = [st.get("vpls_used") for st in steady if st.get("vpls_used") is not None]
        ind = [np.mean(x) for x in seq.indirect if x is not None]
        bright = float(np.mean(ind) / ref_mean) if ind and ref_mean > 0 else float("nan")
        te = tk["per_label"](seq.indirect, bright)
        out[label] = {"E": s["E"], "E_prime": s["E_prime"], **te, "relmse": s["mean"]["relmse"],
                      "ms_per_frame": s["ms_per_frame"], "stage_ms": s["stage_ms"],
                      "brightness": bright,
                      "vpls_used": float(np.mean(used)) if used else None,
                      "vpl_budget": steady[0].get("vpl_budget") if steady else None,
                      "tracked_pixels": s.get("tracked_pixels"), "tracked_spp": tk["spp"],
                      "exposure": tk["exposure"], "failed": bool(s.get("failed")),
                      "nonfinite_pixels": int(s.get("nonfinite_pixels", 0)),
                      "nonfinite_frames": int(s.get("nonfinite_frames", 0))}
    return out


def tracked_measure(run: dict, rs: dict, cfg: dict, own: bool) -> dict:
    """The Sec. 5.2 measurement of the 8 tracked pixels for this sequence (issue 42): their reference (``own``:
    >= :data:`TRACKED_SPP_MIN_SMCIR` spp per pixel as two independent halves, whose difference gives its own
    |E|, |E'| floor; else the harness's) and Reinhard's key of the image reference sequence. Returns
    ``{'spp', 'exposure', 'floor', 'per_label'}``; ``per_label(images, brightness)`` gives a technique's
    ``E_tracked`` / ``E_prime_tracked`` (Reinhard's key, the table's), the same at the fixed k = 1
    (``*_k1``), brightness-normalised (``*_norm``: the estimate over its brightness) and the floor's."""
    refs, scene = rs["refs"], run["scene"]
    pix = refs.tracked["pixels"]
    floor = {"E": float("nan"), "E_prime": float("nan")}
    key = tracked_exposure(refs, "auto")
    if own:
        spp = max(TRACKED_SPP_MIN_SMCIR, min(TRACKED_SPP_MAX, TRACKED_SPP_FACTOR * int(cfg["ref_spp"])))
        h = [cached_tracked_halves(scene, scene.frame_time(i), cfg["res"], pix, spp, run["ref_depth"], True)
             for i in range(int(cfg["frames"]))]
        vals = np.stack([x[0] for x in h])
        floor = tracked_reference_floor(np.stack([x[1] for x in h]), np.stack([x[2] for x in h]), key)
    else:
        spp, vals = int(refs.tracked["spp"]), np.asarray(refs.tracked["values"])

    def per_label(images, brightness):
        main = tracked_temporal(images, vals, pix, key)
        k1 = tracked_temporal(images, vals, pix, 1.0)
        ok = np.isfinite(brightness) and brightness > 0
        norm = tracked_temporal(images, vals, pix, key, 1.0 / brightness) if ok else {"E": float("nan"),
                                                                                      "E_prime": float("nan")}
        return {"E_tracked": float(main["E"]), "E_prime_tracked": float(main["E_prime"]),
                "E_tracked_k1": float(k1["E"]), "E_prime_tracked_k1": float(k1["E_prime"]),
                "E_tracked_norm": float(norm["E"]), "E_prime_tracked_norm": float(norm["E_prime"]),
                "floor_E_tracked": floor["E"], "floor_E_prime_tracked": floor["E_prime"]}
    return {"spp": int(spp), "exposure": float(key), "floor": floor, "per_label": per_label}


FIGURES_FILE = "figures.json"


def _pair_key(scene_name: str, cfg: dict, seed: int, reference: str, untextured: bool, tracked: bool) -> dict:
    """What identifies one (sequence, seed) run's figures: a saved file is reused only when all of it matches."""
    return {"scene": scene_name, "seed": int(seed), "res": list(cfg["res"]), "frames": int(cfg["frames"]),
            "ref_spp": int(cfg["ref_spp"]), "specs": list(cfg["specs"]), "reference": reference,
            "untextured": bool(untextured), "tracked": bool(tracked), "measure": MEASURE_VERSION}


def run_pair(scene_name: str, cfg: dict, out_root: str, seed: int, quiet: bool = True, reference: str = "path",
             untextured: bool = False, tracked: bool = True) -> tuple[dict, bool]:
    """(figures, was_saved): :func:`run_scene` on ``out_root/SEQ/seedN``, its figures saved there as
    ``figures.json`` as soon as it ends, and read back instead of rerun when that file exists with the same
    settings (our choice: a full run is hours on a small CPU, so it can be resumed or split over processes;
    the references themselves are cached on disk by scene state, shared by every seed)."""
    out_dir = os.path.join(out_root, scene_name, f"seed{int(seed)}")
    path = os.path.join(out_dir, FIGURES_FILE)
    key = _pair_key(scene_name, cfg, seed, reference, untextured, tracked)
    try:
        with open(path) as f:
            saved = json.load(f)
        if saved.get("key") == key:
            return saved["figures"], True
    except (OSError, ValueError, KeyError):
        pass
    t0 = time.time()
    figs = run_scene(scene_name, cfg, out_dir, quiet, reference, untextured, tracked, seed)
    tmp = path + f".{os.getpid()}.tmp"
    with open(tmp, "w") as f:
        json.dump({"key": key, "wall_s": time.time() - t0, "figures": figs}, f, indent=1,
                  default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))
    os.replace(tmp, path)
    return figs, False


def parse_pairs(items) -> list[tuple[str, int]]:
    """``['maze:0,1', 'street-canyon']`` as (sequence, seed) pairs (no seeds: seed 0); unknown sequences and
    bad seeds are one :class:`DyngiError` naming the valid ones, before any work."""
    names = [sc for sc, _ in SEQUENCES]
    out = []
    for item in items:
        scene, _, seeds = str(item).partition(":")
        if scene not in names:
            raise DyngiError(f"--only: unknown smcir sequence '{scene}'; valid sequences: {', '.join(names)}")
        try:
            sds = [int(x) for x in (seeds or "0").split(",") if x.strip()]
        except ValueError:
            raise DyngiError(f"--only {item}: seeds must be comma-separated integers >= 0") from None
        if not sds or min(sds) < 0:
            raise DyngiError(f"--only {item}: seeds must be comma-separated integers >= 0")
        out += [(scene, sd) for sd in sds if (scene, sd) not in out]
    return out


def run_pairs(out_root: str, pairs, quick: bool = False, quiet: bool = True, reference: str = "path",
              untextured: bool = False, tracked: bool = True, on_pair=None) -> list[dict]:
    """Only these (sequence, seed) runs of the reproduction (full configuration, or quick), one after the
    other, each saved as it ends and skipped when already saved (:func:`run_pair`): a full run split over
    processes or sessions (ours: hours on a small CPU). ``on_pair(record)`` after each; returns the records
    (sequence, seed, whether it was saved before, wall seconds, load, |E'| per technique)."""
    check_reference(reference, True)
    cfg = SMCIR_QUICK if quick else SMCIR_FULL
    out = []
    for scene, sd in pairs:
        t0 = time.time()
        got, cached = run_pair(scene, cfg, out_root, sd, quiet, reference, untextured, tracked)
        rec = {"scene": scene, "seed": sd, "cached": cached, "wall_s": round(time.time() - t0, 1),
               "load": os.getloadavg()[0], "E'": {k: round(v["E_prime_tracked"], 4) for k, v in got.items()}}
        out.append(rec)
        if on_pair is not None:
            on_pair(rec)
    return out


def _pair_walls(out_root: str, pairs) -> dict:
    """``{'SEQ/seedN': seconds}``: each (sequence, seed) run's own wall time, as its figures.json saved it."""
    out = {}
    for sc, sd in pairs:
        try:
            with open(os.path.join(out_root, sc, f"seed{int(sd)}", FIGURES_FILE)) as f:
                out[f"{sc}/seed{int(sd)}"] = float(json.load(f)["wall_s"])
        except (OSError, ValueError, KeyError):
            pass
    return out


def _pair_figures(*args) -> dict:
    """:func:`run_pair`'s figures alone (one task of the reproduction)."""
    return run_pair(*args)[0]


def _method_label(specs, method):
    return next(s for s in specs if s.split(":")[0] == method)


def _stats(runs: list, label: str, key: str) -> tuple:
    """(mean, min, max, per-seed values) of ``key`` over the seeds' runs."""
    v = np.array([r[label][key] for r in runs], np.float64)
    return float(np.mean(v)), float(np.min(v)), float(np.max(v)), v


def _fmt(st) -> str:
    m, lo, hi, v = st
    return f"{m:.4f}" if len(v) == 1 else f"{m:.4f} [{lo:.4f}-{hi:.4f}]"


def ranking(runs: list, specs, key: str = "E_prime_tracked") -> dict:
    """smcir against the paper's other three on ``key`` over the seeds: its rank per seed (1 = lowest),
    the best other method, the paired differences and their 95% t interval, and ``stable`` (the same
    rank on every seed, or the interval excludes 0; None with one seed)."""
    from scipy import stats as sst

    labels = [_method_label(specs, m) for m in METHODS]
    vals = np.array([[r[lab][key] for lab in labels] for r in runs], np.float64)     # seeds x methods
    ours = METHODS.index("smcir")
    ranks = [int(1 + np.sum(row < row[ours])) for row in vals]
    others = [i for i in range(len(METHODS)) if i != ours]
    best = others[int(np.argmin(vals[:, others].mean(axis=0)))]
    diff = vals[:, ours] - vals[:, best]
    if len(diff) > 1:
        half = float(sst.t.ppf(0.975, len(diff) - 1) * diff.std(ddof=1) / np.sqrt(len(diff)))
    else:
        half = float("inf")
    lo, hi = float(diff.mean() - half), float(diff.mean() + half)
    stable = (len(set(ranks)) == 1 or lo > 0 or hi < 0) if len(diff) > 1 else None    # one seed: not judged
    return {"ranks": ranks, "best_other": METHODS[best], "diff_mean": float(diff.mean()), "ci95": (lo, hi),
            "stable": stable, "lowest": bool(np.mean(vals[:, ours]) <= np.min(vals[:, others].mean(axis=0)))}


def _rows(figs: dict, cfg: dict) -> list:
    """``figs``: scene -> list over seeds of run_scene's dicts."""
    rows = []
    specs = cfg["specs"]
    labels = [_method_label(specs, m) for m in METHODS]
    n_lowest_d = n_within_e = 0
    for scene, what in SEQUENCES:
        if scene not in figs:
            continue
        runs = figs[scene]
        pe, pd = TABLE1[scene]
        es = {m: _stats(runs, l, "E_tracked") for m, l in zip(METHODS, labels)}
        ds = {m: _stats(runs, l, "E_prime_tracked") for m, l in zip(METHODS, labels)}
        best_e = min(METHODS, key=lambda m: es[m][0])
        rk = ranking(runs, specs)
        n_lowest_d += rk["lowest"]
        within = es["smcir"][0] <= 1.2 * min(es[m][0] for m in METHODS if m != "smcir")
        n_within_e += within
        rows.append((f"{scene} ({what}): |E|, 8 px (mean [min-max] over {len(runs)} seeds)",
                     ", ".join(f"{m} {v:.4f}" for m, v in zip(METHODS, pe)) + f"; lowest {METHODS[int(np.argmin(pe))]}",
                     ", ".join(f"{m} {_fmt(es[m])}" for m in METHODS) + f"; lowest {best_e}; smcir / best other "
                     f"{es['smcir'][0] / max(min(es[m][0] for m in METHODS if m != 'smcir'), 1e-30):.2f}x"))
        rows.append((f"{scene}: |E'|, 8 px",
                     ", ".join(f"{m} {v:.4f}" for m, v in zip(METHODS, pd)) + f"; lowest {METHODS[int(np.argmin(pd))]}",
                     ", ".join(f"{m} {_fmt(ds[m])}" for m in METHODS)
                     + f"; smcir's rank per seed {rk['ranks']} (verdicts above), "
                     f"minus {rk['best_other']} {rk['diff_mean']:+.4f} (95% [{rk['ci95'][0]:+.4f}, "
                     f"{rk['ci95'][1]:+.4f}]): "
                     + {True: "stable", False: "NOT stable", None: "one seed: stability not judged"}[rk["stable"]]))
        extra = [s for s in specs if s not in labels]
        rows.append((f"{scene}: other rows, |E| / |E'| (8 px)", "not in the paper",
                     "; ".join(f"{s}: {_fmt(_stats(runs, s, 'E_tracked'))} / {_fmt(_stats(runs, s, 'E_prime_tracked'))}"
                               for s in extra)))
        k_rows = [s for s in specs if s.split(":")[0] == "smcir"]
        fl = runs[0][labels[3]]
        rows.append((f"{scene}: |E'| brightness-normalised (each estimate over its brightness), |E'| at exposure k = 1, "
                     f"and the tracked reference's own floor",
                     "no figure (the paper's reference: 692,100 spp)",
                     ", ".join(f"{m} {_fmt(_stats(runs, l, 'E_prime_tracked_norm'))}" for m, l in zip(METHODS, labels))
                     + "; exposure k = 1: " + ", ".join(f"{m} {_stats(runs, l, 'E_prime_tracked_k1')[0]:.4f}"
                                              for m, l in zip(METHODS, labels))
                     + f"; floor |E| {fl.get('floor_E_tracked', float('nan')):.4f}, |E'| "
                       f"{fl.get('floor_E_prime_tracked', float('nan')):.4f} ({fl.get('tracked_spp')} spp, "
                       f"Reinhard key {fl.get('exposure', float('nan')):.3g})"))
        rows.append((f"{scene}: brightness (mean indirect / reference) of the smcir rows (Eq. 8's readings)",
                     "no figure",
                     "; ".join(f"{s}: {_stats(runs, s, 'brightness')[0]:.3f}" for s in k_rows)
                     + f"; all pixels |E|/|E'|: " + ", ".join(
                         f"{m} {_stats(runs, l, 'E')[0]:.4f}/{_stats(runs, l, 'E_prime')[0]:.4f}"
                         for m, l in zip(METHODS, labels))
                     + f"; ir used {np.mean([r[labels[1]]['vpls_used'] or 0 for r in runs]):.0f} of "
                       f"{runs[0][labels[1]]['vpl_budget']} VPLs"))
    n = sum(1 for sc, _ in SEQUENCES if sc in figs)
    rows.append(("targets (the paper's ranking)", "lowest |E'| on 5/5, lowest |E| on 4/5",
                 f"smcir lowest |E'| on {n_lowest_d}/{n}; |E| within 1.2x of the best other on {n_within_e}/{n}"))
    # Table 2: per-stage ms of smcir
    for scene, _ in SEQUENCES:
        if scene not in figs:
            continue
        lab = _method_label(specs, "smcir")
        stl = [r[lab]["stage_ms"] for r in figs[scene]]
        st = {k: float(np.mean([x.get(k, 0.0) for x in stl])) for k in set().union(*stl)}
        paper = {"corridor-walk": "Soda Hall", "street-canyon": "Epic Citadel", "maze": "Maze",
                 "atrium-sun": "Crytek Sponza", "street-canyon-moving-sun": "Epic Citadel"}[scene]
        pv = TABLE2[paper]
        sampling = sum(st.get(k, 0.0) for k in ("candidates", "resampling", "visibility", "radiosity", "knn"))
        rows.append((f"{scene}: smcir ms per stage (Table 2, {paper})",
                     ", ".join(f"{TABLE2_STAGES[k]} {v}" for k, v in zip(TABLE2_STAGES, pv))
                     + f"; sampling total {sum(pv[:5]):.1f} (GTX Titan X, 1920x1080, shadow maps)",
                     ", ".join(f"{TABLE2_STAGES[k]} {st.get(k, 0.0):.1f}" for k in TABLE2_STAGES)
                     + f"; sampling total {sampling:.1f} (CPU, {cfg['res'][0]}x{cfg['res'][1]}, ray-traced)"))
    return rows


def _plot(figs: dict, cfg: dict, out_dir: str) -> None:
    """flicker.png and error.png at the top level: |E'| and |E| per sequence and technique, mean and
    min-max over the seeds, the paper's values as open markers (its four methods)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = [s for s, _ in SEQUENCES if s in figs]
    specs = list(cfg["specs"])
    for key, idx, name in (("E_prime_tracked", 1, "flicker.png"), ("E_tracked", 0, "error.png")):
        fig, ax = plt.subplots(figsize=(10, 4))
        wdt = 0.8 / len(specs)
        for j, s in enumerate(specs):
            x = np.arange(len(scenes)) + (j - len(specs) / 2 + 0.5) * wdt
            st = [_stats(figs[sc], s, key) for sc in scenes]
            m = np.array([a[0] for a in st])
            err = np.array([[a[0] - a[1] for a in st], [a[2] - a[0] for a in st]])
            ax.bar(x, m, wdt, yerr=err, label=s, capsize=2)
            if s in [_method_label(specs, mm) for mm in METHODS]:
                mi_ = METHODS.index(s.split(":")[0])
                ax.plot(x, [TABLE1[sc][idx][mi_] for sc in scenes], "k_", markersize=8)
        ax.set_xticks(np.arange(len(scenes)))
        ax.set_xticklabels(scenes, fontsize=8)
        ax.set_ylabel(("|E'|" if idx else "|E|") + " (8 tracked px); black ticks: the paper")
        ax.legend(fontsize=7, ncol=3)
        fig.tight_layout()
        fig.savefig(os.path.join(out_dir, name), dpi=90)
        plt.close(fig)


TABLE1_QUOTE = ("Table 1: with an equal VPL budget, SMC-IR has the lowest temporal flicker |E'| on all five "
                "sequences (e.g. Epic Citadel, moving sun: 0.0071 vs 0.0323 for IR)")
TABLE1_E_QUOTE = ("Table 1: SMC-IR has the lowest average absolute error |E| on four of the five sequences (not "
                  "Crytek Sponza); Sec. 5.2: \"the improved temporal stability does not affect the image quality, "
                  "as the error made by our method is comparable to MIR\"")
QUANTITIES = {"E_prime": ("E_prime_tracked", "|E'| of the 8 tracked pixels (Sec. 5.2, Eq. 10; Reinhard's key)"),
              "E": ("E_tracked", "|E| of the 8 tracked pixels (Sec. 5.2; Reinhard's key)")}
"""The two claims of Table 1: quantity -> (figures key, metric text)."""


def declare_claims(cfg: dict, scene: str, methods=None, quantities=("E_prime",)) -> list:
    """Table 1's claims on one sequence (dyngi.experiments.claims), per other method (MIR, the paper's IR,
    TCAS; ``methods``: a subset), equal VPL budget, per seed: ``'E_prime'``, smcir's tracked-pixel |E'|
    below the method's (every sequence); ``'E'``, its |E| below the method's (the four sequences of
    :data:`TABLE1_E_LOWEST`). The paper-literal row sets Eq. 8's printed reading (``smcir:eq8=text``)."""
    specs = cfg["specs"]
    paper = {"resolution": "1920x1080", "VPLs": "the paper's budget per scene (Sec. 5.3)", "frames": "the sequence",
             "visibility": "128x128 paraboloid shadow maps", "tracked-pixel reference spp": 692100}
    vpls = parse_spec(_method_label(specs, "smcir")).params.get("vpls")
    ours = {"resolution": f"{cfg['res'][0]}x{cfg['res'][1]}",
            "VPLs": f"equal budget, {vpls} for every method" if vpls else "equal budget (the techniques' defaults)",
            "frames": cfg["frames"], "visibility": "ray traced",
            "tracked-pixel reference spp": cfg.get("tracked_spp", "-")}
    out = []
    for q in quantities:
        if q == "E" and scene not in TABLE1_E_LOWEST:
            continue
        key = f"smcir.table1.{scene}.vs-" if q == "E_prime" else f"smcir.table1-E.{scene}.vs-"
        out += [Claim(key + m, PAPER, TABLE1_QUOTE if q == "E_prime" else TABLE1_E_QUOTE, "Table 1",
                      _method_label(specs, "smcir"), _method_label(specs, m), QUANTITIES[q][1], "equal-frames",
                      Criterion("below", 1.0), tuple(int(x) for x in SMCIR_FULL["seeds"]), paper, ours,
                      cost_note="equal VPL budget, as the paper (Sec. 5.3)")
                for m in (methods or METHODS) if m != "smcir"]
    return out


def _label_of(spec: str, specs) -> str | None:
    """The label among ``specs`` that runs ``spec`` (the same technique and settings), or None."""
    want = parse_spec(spec)
    for s in specs:
        got = parse_spec(s)
        if got.name == want.name and dict(got.params) == dict(want.params):
            return s
    return None


def decide_claims(figs: dict, cfg: dict, quick: bool) -> list:
    """Both Table 1 claims on every sequence run, from the per-seed figures: each claim row (default,
    paper-literal, baseline) takes the figures of the spec that ran it; a row no spec ran stays out
    (:func:`dyngi.experiments.claims.decide` says so)."""
    out = []
    for sc, runs in figs.items():
        for c in declare_claims({**cfg, "tracked_spp": runs[0][_method_label(cfg["specs"], "smcir")].get("tracked_spp")},
                                sc, quantities=tuple(QUANTITIES)):
            key = QUANTITIES["E" if ".table1-E." in c.key else "E_prime"][0]
            vals = {}
            for r in claim_rows(c, quick):
                lab = _label_of(r.spec, cfg["specs"])
                if lab is not None:
                    vals[r.label] = {int(sd): d[lab][key] for sd, d in zip(cfg["seeds"], runs)}
            out.append(result_from_values(c, vals, quick))
    return out


def claim_summary(results: list) -> list[str]:
    """Per claim family and sequence, the verdict words against each method (computed, never written)."""
    lines = []
    for name, tag in (("|E'| lowest (every sequence)", ".table1."), ("|E| lowest (Table 1's four)", ".table1-E.")):
        by = {}
        for r in results:
            if tag in r.claim.key:
                sc = r.claim.key.split(tag)[1].split(".vs-")[0]
                by.setdefault(sc, []).append(f"vs {r.claim.key.split('.vs-')[1]}: {r.verdict.word}")
        lines += [f"* {name}: " + "; ".join(f"{sc}: " + ", ".join(v) for sc, v in by.items())]
    return lines


@register_experiment("smcir", "SMC-IR Table 1 (|E|, |E'| of 8 tracked pixels: MIR, IR, TCAS, SMC-IR, equal VPL "
                     "budget, 3 seeds) and Table 2 (stage ms) on five analog sequences", PAPER)
def reproduce_smcir(out_dir: str, quick: bool = False, quiet: bool = True, reference: str = "path",
                    untextured: bool = False, tracked: bool = True, config: dict | None = None) -> str:
    """The ``smcir`` experiment (module docstring); ``quick``: :data:`SMCIR_QUICK`, else :data:`SMCIR_FULL`;
    ``config`` (Python API only): keys of :data:`CONFIG_KEYS` overriding the chosen one (a scaled run).

    ``reference``: ``'path'`` (the path-traced indirect reference, Sec. 5.2) or ``'clamped'`` (clamped
    path tracing, Sec. 5.4); ``untextured``: average albedos (Sec. 5); ``tracked=False``: no per-pixel
    tracked reference (the image reference's values stand in); the CLI's ``--reference``,
    ``--untextured``, ``--no-tracked``."""
    check_reference(reference, True)
    cfg = dict(SMCIR_QUICK if quick else SMCIR_FULL)
    bad = sorted(set(config or {}) - set(CONFIG_KEYS))
    if bad:
        raise DyngiError(f"unknown smcir reproduction setting(s) {', '.join(bad)}; valid: {', '.join(CONFIG_KEYS)}")
    cfg.update(config or {})
    missing = [m for m in METHODS if not any(s.split(":")[0] == m for s in cfg["specs"])]
    if missing or not cfg["seeds"]:
        raise DyngiError(f"the smcir reproduction needs {', '.join(METHODS)} among its techniques and >= 1 seed")
    t0 = time.time()
    pairs = [(sc, int(sd)) for sc in cfg["scenes"] for sd in cfg["seeds"]]   # independent runs: tasks (--cluster)
    got = cluster.run_named([f"{sc}/seed{sd}" for sc, sd in pairs], _pair_figures,
                            [(sc, cfg, out_dir, sd, quiet, reference, untextured, tracked) for sc, sd in pairs],
                            "reproduce smcir", quiet)
    figs = {sc: [got[f"{sc}/seed{int(sd)}"] for sd in cfg["seeds"]] for sc in cfg["scenes"]   # all seeds or none
            if all(f"{sc}/seed{int(sd)}" in got for sd in cfg["seeds"])}
    wall = time.time() - t0
    pair_walls = _pair_walls(out_dir, pairs)
    results = decide_claims(figs, cfg, quick)
    rows = _rows(figs, cfg)
    _plot(figs, cfg, out_dir)
    ref_text = ("clamped path-traced (Sec. 5.4) indirect reference" if reference == "clamped" else
                "path-traced indirect reference") + (", untextured (average albedos)" if untextured else "")
    tspp = {f[_method_label(cfg["specs"], "smcir")].get("tracked_spp") for runs in figs.values() for f in runs}
    tr_text = (f"tracked pixels {', '.join(map(str, sorted(x for x in tspp if x)))} spp as two independent halves"
               if tracked and reference == "path" else "tracked pixels 16x that" if tracked
               else "tracked pixels read from the image reference")
    full = {k: cfg[k] for k in CONFIG_KEYS} == {k: SMCIR_FULL[k] for k in CONFIG_KEYS}
    md = "\n".join([f"# reproduce smcir ({'full' if full else 'quick' if quick else 'scaled'} run)", "",
                    "SMC-IR: " + PAPER + ".",
                    f"Techniques {', '.join(cfg['specs'])}; {cfg['frames']} frames at {cfg['res'][0]}x{cfg['res'][1]}, "
                    f"seeds {', '.join(map(str, cfg['seeds']))}, indirect light only against the {ref_text} "
                    f"(max depth 5, {cfg['ref_spp']} spp; {tr_text}), |E| and |E'| after Reinhard tone mapping at the key "
                    "of the image reference sequence, equal VPL budget; per-sequence, per-seed "
                    "reports in the sub-folders. Visibility is ray-traced (our substitution for 128x128 "
                    f"paraboloid shadow maps). Wall time {wall / 60:.1f} min (this call); the (sequence, seed) runs "
                    f"took {sum(pair_walls.values()) / 60:.1f} min together when they ran (figures.json).", "",
                    "## Verdicts (computed: dyngi.experiments.claims)", "", *verdict_table(results), "",
                    *claim_summary(results), "",
                    *[line for r in results for line in r.markdown()],
                    "## Figures beside the paper's", "",
                    paper_table(rows), "",
                    *cluster.failure_notes()])
    return write_summary(out_dir, md, {
        "paper.json": {"experiment": "smcir", "quick": quick, "paper": PAPER, "figures": figs,
                       "config": {k: cfg[k] for k in CONFIG_KEYS}, "wall_s": wall, "pair_wall_s": pair_walls,
                       "ranking": {sc: ranking(figs[sc], cfg["specs"]) for sc in figs},
                       "reference": reference, "untextured": bool(untextured), "tracked": bool(tracked),
                       "rows": [{"quantity": q, "paper": p, "ours": o} for q, p, o in rows]},
        # every run, as the CLI reads it
        "summary.json": {"experiment": "smcir", **claims_json(results), "techniques": {f"{sc}/seed{sd}/{lab}": v
                                                               for sc, runs in figs.items()
                                                               for sd, d in zip(cfg["seeds"], runs)
                                                               for lab, v in d.items()}}})
