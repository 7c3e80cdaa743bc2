"""``dyngi compare``: several techniques on one animated scene against the ground truth.

Writes into ``out_dir`` (atomically: a temporary folder moved into place at the end):

* ``metrics.csv``     technique x frame x metric (mse, relmse, mape, flip, ssim), NaN/Inf and negative
                      pixel counts, ms and rays;
* ``summary.md``      per technique: mean error by metric, |E| and |E'| (SMC-IR Sec. 5.2),
                      ms per frame by stage, rays per frame; the reference's own noise; budget accounting;
                      failures (NaN/Inf pixels);
* ``plots/``          error vs frame, error vs cumulative wall time, stage-time bars (matplotlib);
* ``grid_NNNN.png``   for chosen frames: each technique, the reference and the FLIP error map;
* ``side_by_side.mp4`` reference and techniques next to each other, labelled;
* ``<technique>/frame_NNNN.png`` and ``.exr`` every frame, and ``report.html``, self-contained.

Techniques are given as specs ``NAME[:KEY=VALUE...]`` (:func:`dyngi.techniques.base.parse_spec`) and
labelled by the spec as typed, so ``ddgi,ddgi:hysteresis=0.9`` runs two settings side by side.
``params`` (``--set``): ``NAME.KEY=VALUE`` applies to every spec of technique NAME, ``KEY=VALUE`` to
every compared technique that has KEY; a spec's own settings win.

Each technique's sequence is one task of the job's executor (:mod:`~dyngi.experiments.cluster`,
``--cluster``): in this process one after another by default, exactly as before; on a Ray cluster the
missing references are rendered first as chunk tasks (:func:`~dyngi.experiments.reference_job.reference_job`),
then every sequence runs on a worker that loads the scene and makes the technique itself (under a budget,
the first technique first), and the images come back here to be measured and written. A technique that
fails there (after retries) is left out with a warning; the rest is written.

This module orchestrates; budgets are :mod:`~dyngi.experiments.budgets`, measuring is
:mod:`~dyngi.experiments.evaluate`, the files are :mod:`~dyngi.experiments.report`.
"""
from __future__ import annotations

import os
import sys
import time

from ..backend import mi
from ..errors import DyngiError
from ..scene import load_scene
from ..scene.untextured import make_untextured
from ..techniques.base import REGISTRY, TechniqueSpec, as_spec, create_technique, get_technique, technique_names
from ..vpl.shading import clamp_value
from . import cluster
from .budgets import budget_accounting, run_with_budget
from .cluster import Task, TaskFailure, describe_error, failed, scene_ref
from .denoise import aux_buffers, denoise, require
from .evaluate import (LABELS, METRIC_NAMES, check_metric_names, collect_clamped_references,  # noqa: F401
                       collect_references, evaluate_sequence, failures, indirect_reference_fn, summarize_noise)
from .io import atomic_output_dir, check_writable
from .reference_job import reference_job
from .references.clamped import check_reference, reference_clamp_distance
from .references.path import DEFAULT_REF_SPP, half_spp, scene_max_depth
from .report import write_outputs
from .runner import BUDGETS, SequenceResult, run_round_robin


def parse_specs(techniques) -> list[TechniqueSpec]:
    """Specs of a list of technique texts (each ``NAME[:KEY=VALUE...]``) or of :class:`TechniqueSpec`
    objects already parsed at the edge (kept as they are); a label given twice is an error."""
    if not techniques:
        raise DyngiError("no techniques given; e.g. --techniques path,ddgi")
    specs = [as_spec(t if isinstance(t, TechniqueSpec) else str(t).strip()) for t in techniques]
    labels = [s.label for s in specs]
    if len(set(labels)) != len(labels):
        raise DyngiError(f"a technique is listed twice in '{','.join(labels)}'")
    return specs


def split_params(techniques, params: dict) -> dict[str, dict]:
    """``--set`` settings per label: ``name.key=value`` to every spec of technique ``name``;
    ``key=value`` to every compared technique that has ``key``; then each spec's own settings win.

    ``techniques``: labels, spec texts or :class:`TechniqueSpec` objects.
    """
    specs = [as_spec(t) for t in techniques]
    bases = sorted({s.name for s in specs})
    out = {s.label: {} for s in specs}
    for k, v in (params or {}).items():
        if "." in k:
            t, key = k.split(".", 1)
            takers = [s for s in specs if s.name == t]
            if not takers:
                raise DyngiError(f"--set '{k}' names technique '{t}' which is not compared; "
                                 f"compared techniques: {', '.join(bases)}")
            if key not in get_technique(t).PARAMS:
                raise DyngiError(f"unknown parameter '{key}' for technique '{t}'; valid parameters: "
                                 + (", ".join(sorted(get_technique(t).PARAMS)) or "(none)"))
            for s in takers:
                out[s.label][key] = v
        else:
            takers = [s for s in specs if k in get_technique(s.name).PARAMS]
            if not takers:
                valid = sorted({p for s in specs for p in get_technique(s.name).PARAMS})
                raise DyngiError(f"no compared technique has a parameter '{k}'; valid parameters: "
                                 + (", ".join(valid) or "(none)"))
            for s in takers:
                out[s.label][k] = v
    return {s.label: s.merged(out[s.label]) for s in specs}


def run_compare(scene_name: str, techniques: list[str], out_dir: str, frames: int = 30, res=(160, 120),
                budget: str = "equal-frames", seed: int = 0, ref_spp: int | None = None, quiet: bool = False,
                params: dict | None = None, grid_frames: list[int] | None = None,
                metrics: list[str] | None = None, ref_depth: int | None = None, indirect: bool = False,
                scene=None, denoise: bool = False, reference: str = "path", untextured: bool = False,
                tracked: bool = True) -> str:
    """Run the comparison and write the outputs described in the module docstring; return ``out_dir``.

    ``techniques``: specs ``NAME[:KEY=VALUE...]``. ``metrics``: names from :data:`dyngi.metrics.METRICS`
    (default all five). HDR-FLIP costs ~10 us per pixel on 2 CPU cores (docs/harness.md); leave it
    out for long sequences (the FLIP maps of the image grid are computed regardless). ``ref_depth``:
    the reference's max depth (default: the scene's own, :func:`~dyngi.experiments.references.path.scene_max_depth`).
    ``indirect``: compare the techniques' indirect-only images (``FrameResult.indirect``) against an
    indirect-only reference. ``scene``: an already loaded Scene instead of ``scene_name``.
    ``denoise``: also report every technique denoised by Intel OIDN (label ``<spec>+denoise``; see
    :func:`add_denoised`). ``reference``: ``'path'`` (default) or ``'clamped'`` (clamped path tracing,
    SMC-IR Sec. 5.4, indirect only: :mod:`~dyngi.experiments.references.clamped`). ``untextured``: every
    texture replaced by its mean colour for the techniques and the reference (SMC-IR Sec. 5,
    :mod:`dyngi.scene.untextured`). ``tracked=False``: no per-pixel reference for the 8 tracked pixels
    (the image reference's values stand in).
    """
    res = tuple(res)
    run = prepare(scene_name, techniques, out_dir, frames, budget, ref_spp, params, metrics, ref_depth,
                  indirect, scene, reference=reference, untextured=untextured, tracked=tracked)
    run["denoise"] = [lb for lb in run["labels"] if denoise or run["specs"][lb].denoise]
    if run["denoise"]:
        require()
    rs = execute(run, res, seed, quiet)
    with atomic_output_dir(run["out_dir"]) as tmp:
        write_outputs(tmp, run["scene"], run["labels"], run["specs"], rs["results"], rs["refs"], rs["rows"],
                      rs["summary"], rs["ctx"], run["names"], grid_frames)
    return run["out_dir"]


def prepare(scene_name, techniques, out_dir, frames, budget, ref_spp, params, metrics, ref_depth, indirect,
            scene=None, reference: str = "path", untextured: bool = False, tracked: bool = True) -> dict:
    """Validate everything before any work; load the scene and create the techniques."""
    names = check_metric_names(metrics)
    specs = parse_specs(techniques)
    if budget not in BUDGETS:
        raise DyngiError(f"unknown budget '{budget}'; valid budgets: {', '.join(BUDGETS)}")
    if frames < 1:
        raise DyngiError(f"--frames must be >= 1, got {frames}")
    spp = DEFAULT_REF_SPP if ref_spp is None else ref_spp
    half_spp(spp)
    if ref_depth is not None and not (isinstance(ref_depth, int) and (ref_depth >= 1 or ref_depth == -1)):
        raise DyngiError(f"--ref-depth must be >= 1 or -1 (unbounded), got {ref_depth!r}")
    if indirect:
        indirect_reference_fn()
        if ref_depth is not None and 1 <= ref_depth <= 2:
            raise DyngiError(f"--indirect needs --ref-depth > 2 (or -1): depth {ref_depth} has no indirect light")
    check_reference(reference, indirect)
    check_writable(out_dir)
    per_tech = split_params(specs, params or {})
    scene = scene if scene is not None else load_scene(scene_name)
    if untextured:
        make_untextured(scene)
    techs = {s.label: create_technique(s.name, scene, per_tech[s.label]) for s in specs}
    warnings = _check_indirect(scene, techs, specs) if indirect else []
    ref_depth, depth_notes = _reference_depth(scene, techs, specs, ref_depth, scene_max_depth)
    warnings += depth_notes
    clamp = reference_clamp_distance(techs) if reference == "clamped" else None
    return {"reference": reference, "ref_clamp_distance": clamp, "untextured": bool(untextured),
            "tracked": bool(tracked), "scene": scene, "specs": {s.label: s for s in specs},
            "labels": [s.label for s in specs],
            "scene_name": scene_name, "params": per_tech,
            "techs": techs, "names": names, "budget": budget, "frames": frames, "ref_spp": spp,
            "ref_depth": ref_depth, "indirect": indirect,
            "out_dir": os.path.abspath(out_dir), "warnings": warnings}


def _reference_depth(scene, techs, specs, ref_depth, scene_max_depth) -> tuple[int, list[str]]:
    """The reference's path depth and notes about it.

    A technique of fixed depth declares ``REFERENCE_DEPTH`` (Mitsuba's vertex count; ``nee-pt``: 3, the
    VLC paper's 5-ray path). Without ``--ref-depth``, when every compared technique declares the same
    depth, the reference is rendered at it (so the error measures noise, not truncation) and a note says
    so; when only some declare one, the scene's depth is kept and a note names the techniques whose error
    then includes their truncation. An explicit ``--ref-depth`` always wins."""
    declared = {s.label: getattr(type(techs[s.label]), "REFERENCE_DEPTH", None) for s in specs}
    fixed = {k: v for k, v in declared.items() if v is not None}
    if ref_depth is not None or not fixed:
        return (scene_max_depth(scene) if ref_depth is None else ref_depth), []
    if len(fixed) == len(declared) and len(set(fixed.values())) == 1:
        d = next(iter(fixed.values()))
        return d, [f"reference rendered at depth {d}, the fixed path depth of {', '.join(fixed)} "
                   f"(--ref-depth overrides)"]
    d = scene_max_depth(scene)
    return d, [f"{k}: fixed path depth {v} against a depth-{d} reference: its error includes the light "
               f"of longer paths (compare it alone, or pass --ref-depth {v})" for k, v in fixed.items()]


def _check_indirect(scene, techs, specs) -> list[str]:
    """Every technique must return ``FrameResult.indirect``: those that declare ``HAS_INDIRECT = False``
    fail here, before any work; undeclared ones are checked on their first frame.

    Returns warnings: a probe technique that declares ``INDIRECT_INCLUDES_PROBE_SKY`` counts the sky its
    probes carry as indirect light (no bounced-only probe channel), which the indirect-only reference does
    not; on a scene with an environment emitter its ``--indirect`` error is then inflated."""
    lack = [s.label for s in specs if getattr(type(techs[s.label]), "HAS_INDIRECT", None) is False]
    if lack:
        raise _no_indirect(lack)

    has_env = any(mi.has_flag(e.flags(), mi.EmitterFlags.Infinite) and
                  not mi.has_flag(e.flags(), mi.EmitterFlags.DeltaDirection) for e in scene.mi_scene.emitters())
    warn = []
    for s in specs:
        t = techs[s.label]
        if has_env and getattr(type(t), "INDIRECT_INCLUDES_PROBE_SKY", False) and \
                t.params.get("direct", "nee") != "nee":
            warn.append(f"{s.label}: its probes carry the sky, which its indirect image then includes "
                        f"(the reference's does not); use {s.name}:direct=nee for a true indirect image")
    for w in warn:
        print(f"dyngi: warning: {w}", file=sys.stderr)
    return warn


def _no_indirect(labels) -> DyngiError:
    technique_names()
    have = sorted(n for n, c in REGISTRY.items() if getattr(c, "HAS_INDIRECT", None))
    return DyngiError(f"--indirect: technique(s) {', '.join(labels)} return no indirect-only image "
                      "(FrameResult.indirect); techniques with one: " + (", ".join(have) or "(none)"))


def execute(run: dict, res, seed: int, quiet: bool = True) -> dict:
    """References, every technique under the budget, evaluation: ``{'results', 'refs', 'rows', 'summary', 'ctx'}``."""
    scene, labels, frames, budget = run["scene"], run["labels"], run["frames"], run["budget"]
    ex = cluster.current()
    bar = prog = None
    if ex.in_process:     # one process: the frame bar, as always
        if not quiet:
            from tqdm import tqdm
            bar = tqdm(total=frames * (len(labels) + 1), desc=f"compare on {scene.name}", unit="frame",
                       file=sys.stderr)
    else:                 # a cluster: one task bar for the whole job (reference chunks + sequences)
        prog = cluster.Progress(len(labels), f"compare on {scene.name} ({ex.kind}, {ex.workers} workers)", quiet)
        _prefill_references(run, res, ex, prog)
    # -- ground truth (cached), with its own noise --
    tracked_spp = None if run.get("tracked", True) else 0
    if run.get("reference", "path") == "clamped":
        refs, noise = collect_clamped_references(scene, frames, res, run["ref_spp"], run["ref_depth"],
                                                 clamp_value(scene, run["ref_clamp_distance"]), bar, tracked_spp)
    else:
        refs, noise = collect_references(scene, frames, res, run["ref_spp"], run["ref_depth"], run["indirect"],
                                         bar, tracked_spp=tracked_spp)
    # -- every technique (one task each); the first sets the budget --
    try:
        results = run_sequences(run, res, seed, ex, bar, prog)
    finally:
        if prog is not None:
            prog.close()
    for label, seq in results.items():
        if run["indirect"] and any(x is None for x in seq.indirect):
            raise _no_indirect([label])
    labels = run["labels"]
    first = results[labels[0]]
    if bar is not None:
        bar.close()
    # -- metrics --
    rows, summary, accounting = [], {}, {}
    for label, seq in results.items():
        imgs = seq.indirect if run["indirect"] else None
        r, s = evaluate_sequence(label, seq, refs, run["names"], imgs)
        rows += r
        summary[label] = s
        if label != labels[0]:
            accounting[label] = budget_accounting(seq, first, budget)
    if run.get("denoise"):
        add_denoised(run, results, refs, rows, summary, accounting, res, imgs_indirect=run["indirect"])
    warnings = list(run.get("warnings", []))
    for label, seq in results.items():       # what techniques flag about their own frames, once each
        seen = dict.fromkeys(w for st in seq.stats for w in (st.get("warnings") or ()))
        warnings += [f"{label}: {w}" for w in seen]
    if not ex.in_process:
        warnings += cluster_warnings(ex, budget)
    ctx = {"frames": frames, "res": tuple(res), "budget": budget, "seed": seed, "ref_spp": run["ref_spp"],
           "ref_depth": run["ref_depth"], "indirect": run["indirect"], "ref_noise": summarize_noise(noise),
           "accounting": accounting, "warnings": warnings, "notes": []}
    if run.get("reference", "path") == "clamped":
        ctx["notes"].append(f"Reference: clamped path tracing (SMC-IR Sec. 5.4), geometry term from the primary "
                            f"hits clamped at clamp_distance {run['ref_clamp_distance']:g} of the scene diagonal.")
    if run.get("untextured"):
        ctx["notes"].append("Untextured: every texture replaced by its mean colour (SMC-IR Sec. 5), for the "
                            "techniques and the reference.")
    if run.get("denoise"):
        ctx["notes"].append(f"Denoised rows ({DENOISED_SUFFIX}): Intel Open Image Denoise (pyoidn), our substitute "
                            "for the OptiX denoiser of the DDGI Resampling paper, fed with albedo and normal AOVs "
                            "of the primary hits; its time is the stage 'denoise', not charged to the budget.")
    return {"results": results, "refs": refs, "rows": rows, "summary": summary, "ctx": ctx}


class _Live:
    """The scene and techniques this process already made (tasks of an in-process executor use them)."""

    def __init__(self, scene, techs):
        self.scene, self.techs = scene, techs


def _sequence_task(source, label, name, params, frames, res, seed, budget, first, bar=None):
    """One technique's sequence (a task: stateful, so never split). ``source``: :class:`_Live` in-process,
    else a :class:`~dyngi.experiments.cluster.SceneRef` from which the worker loads the scene and makes the
    technique ``name`` with ``params``."""
    if isinstance(source, _Live):
        scene, tech = source.scene, source.techs[label]
    else:
        scene = source.load()
        tech = create_technique(name, scene, params)
    return run_with_budget(scene, tech, frames, res, seed, budget, first, bar, label=label)


def _budget_view(seq):
    """What a budget needs of the first technique's run (its stats and times; no images to ship)."""
    return SequenceResult(seq.technique, times=list(seq.times), stats=list(seq.stats), wall_ms=list(seq.wall_ms))


def run_sequences(run: dict, res, seed: int, ex, bar=None, progress=None) -> dict:
    """``{label: SequenceResult}`` of every technique of ``run``, each one task on ``ex``.

    ``equal-frames``: all at once (in-process: stepped round-robin, frame ``i`` of every technique before
    frame ``i + 1`` of any, :func:`~dyngi.experiments.runner.run_round_robin`, so their timings share the
    machine's load); a budget: the first, then the others with its budget. In-process the tasks use the
    techniques :func:`prepare` made, in order; on a cluster each worker makes its own. A technique that failed (after retries) is dropped from ``run['labels']``
    with a warning; when the budget-setting first one or every one failed, a DyngiError names them."""
    scene, labels, frames, budget = run["scene"], list(run["labels"]), run["frames"], run["budget"]
    if ex.in_process:
        src = _Live(scene, run["techs"])
    else:
        src = run.get("source") or scene_ref(run.get("scene_name") or scene, run.get("untextured", False))

    def task(label, first):
        if first is not None and not ex.in_process:
            first = _budget_view(first)
        return Task(f"{label} on {scene.name} (seed {seed})", _sequence_task,
                    (src, label, run["specs"][label].name, (run.get("params") or {}).get(label, {}), frames,
                     tuple(res), seed, budget, first, bar if ex.in_process else None))

    if ex.in_process and budget == "equal-frames" and len(labels) > 1:
        # stepped round-robin (issue 40): every technique's frame i under the same machine load
        seqs, errors = run_round_robin(scene, {lb: run["techs"][lb] for lb in labels}, frames, res, seed,
                                       progress=bar)
        outs = []
        for lb in labels:
            if lb in errors:
                outs.append(TaskFailure(f"{lb} on {scene.name} (seed {seed})", describe_error(errors[lb]), 1))
                continue
            seqs[lb].technique = lb
            if run["indirect"] and any(x is None for x in seqs[lb].indirect):
                raise _no_indirect([lb])
            outs.append(seqs[lb])
    elif ex.in_process:     # one after another, each checked as it ends, as before executors
        outs, first = [], None
        for lb in labels:
            seq = ex.map([task(lb, first)], progress=progress)[0]
            if not failed(seq) and run["indirect"] and any(x is None for x in seq.indirect):
                raise _no_indirect([lb])
            outs.append(seq)
            if first is None and not failed(seq):
                first = seq
    elif budget == "equal-frames":
        outs = ex.map([task(lb, None) for lb in labels], progress=progress)
    else:
        outs = ex.map([task(labels[0], None)], progress=progress)
        if failed(outs[0]):
            raise DyngiError(f"the first technique sets the {budget} budget and failed: {outs[0]}")
        outs += ex.map([task(lb, outs[0]) for lb in labels[1:]], progress=progress)
    bad = [o for o in outs if failed(o)]
    if len(bad) == len(labels):
        raise DyngiError("every technique failed: " + "; ".join(map(str, bad)))
    results = {lb: o for lb, o in zip(labels, outs) if not failed(o)}
    if bad:
        run["labels"] = [lb for lb in labels if lb in results]
        run.setdefault("warnings", []).extend(f"failed and left out: {o}" for o in bad)
    return results


def _prefill_references(run, res, ex, progress) -> None:
    """On a cluster: render the missing references of the run as chunk tasks first (the image references;
    the clamped kind and the 8 tracked pixels are rendered here as before), so that
    :func:`collect_references` finds them cached."""
    if run.get("reference", "path") != "path":
        return
    source = run.get("source") or scene_ref(run.get("scene_name") or run["scene"], run.get("untextured", False))
    run["source"] = source
    reference_job(run["scene"], run["frames"], res, run["ref_spp"], run["ref_depth"], executor=ex, halves=True,
                  progress=progress, path=not run["indirect"], indirect=run["indirect"], source=source)


def cluster_warnings(ex, budget) -> list[str]:
    """What a report should say about a run on a cluster."""
    out = []
    if budget == "equal-time":
        out.append(f"equal-time budgets measured on {ex.kind} workers ({getattr(ex, 'threads', 1)} Dr.Jit "
                   "thread(s) each, sharing machines with other tasks): frame times are comparable within this run only")
    return out


DENOISED_SUFFIX = "+denoise"


def add_denoised(run: dict, results: dict, refs, rows: list, summary: dict, accounting: dict, res,
                 imgs_indirect: bool = False) -> None:
    """Add ``<label>+denoise`` beside every technique of ``run['denoise']`` (all with ``--denoise``, or
    the specs with ``denoise=true``): its frames denoised by Intel OIDN (our substitute
    for the OptiX denoiser of the DDGI Resampling paper), fed with albedo and normal AOVs of the
    primary hits (:func:`~dyngi.experiments.denoise.aux_buffers`, computed once per frame and shared by
    all techniques). The denoiser's time is reported as the stats stage ``denoise`` of the denoised row
    and is not charged to the technique's budget (the technique ran once, under its budget)."""
    scene, labels = run["scene"], list(run["labels"])
    first = results[labels[0]]
    aux = []
    for t in first.times:
        sc = scene.at(t) if hasattr(scene, "at") else scene
        aux.append(aux_buffers(sc, scene.camera(t), res))
    for label in labels:
        if label not in run["denoise"]:
            continue
        seq = results[label]
        out = SequenceResult(label + DENOISED_SUFFIX, times=list(seq.times), wall_ms=list(seq.wall_ms))
        for i, img in enumerate(seq.images):
            t0 = time.perf_counter()
            src = seq.indirect[i] if imgs_indirect else img
            d = denoise(src, *aux[i])
            ms = (time.perf_counter() - t0) * 1e3
            out.images.append(d if not imgs_indirect else img)
            out.indirect.append(d if imgs_indirect else None)
            st = dict(seq.stats[i])
            st["ms"] = dict(st.get("ms", {}), denoise=ms)
            out.stats.append(st)
        dl = label + DENOISED_SUFFIX
        results[dl] = out
        r, s = evaluate_sequence(dl, out, refs, run["names"], out.indirect if imgs_indirect else None)
        rows += r
        summary[dl] = s
        if label in accounting:
            accounting[dl] = accounting[label]
        run["specs"][dl] = run["specs"][label]
        run["labels"].append(dl)
