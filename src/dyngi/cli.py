"""Command-line interface: a thin layer over the Python API.

    dyngi scenes                       list built-in scenes
    dyngi techniques                   list techniques and their parameters
    dyngi render SCENE --technique T   render frames, video and stats
    dyngi reference SCENE              fill the ground-truth cache
    dyngi compare SCENE --techniques a,b:key=v   metrics, plots, report.html
    dyngi sweep TECH SCENE --grid key=a,b --seeds N   error and time over a parameter grid
    dyngi reproduce NAME [--quick]     a paper's comparison on the analog scenes, beside its figures
    dyngi probe-view SCENE             the probe volume of ddgi as spheres
    dyngi view SCENE [--techniques a,b]  interactive browser viewer (camera, techniques, probes, error view)
    dyngi demo                         the main job: a tour of the five papers, one report.html

Errors caused by input print one line (``dyngi: error: ...``) and exit 2.
"""
from __future__ import annotations

import argparse
import contextlib
import inspect
import json
import os
import sys

from . import backend
from .errors import DyngiError
from .experiments import cluster
from .experiments.cluster import resolve_cluster
from .experiments.compare import parse_specs, run_compare
from .experiments.demo import run_tour, select_sections
from .experiments.evaluate import indirect_reference_fn
from .experiments.io import atomic_output_dir, check_writable, write_exr, write_png
from .experiments.reference_job import reference_job
from .experiments.references.clamped import check_reference
from .experiments.references.path import DEFAULT_REF_SPP, fill_reference_cache, scene_max_depth
from .experiments.render import render_to_dir
from .experiments.reproduce import EXPERIMENTS, experiment_names, get_experiment, run_experiment, smoke_size
from .experiments.reproductions._summary import merged_techniques
from .experiments.reproductions.ddgi_resampling import run_only as resampling_run_only
from .experiments.reproductions.smcir import parse_pairs, run_pairs
from .experiments.reproductions.smcir_table import table_markdown
from .experiments.runner import parse_res, run_sequence
from .experiments.sweep import run_sweep
from .scene import load_scene
from .scene.loaders import scene_options
from .scene.library import BUILTINS, builtin_names, make_builtin
from .techniques.base import REGISTRY, create_technique, get_technique, parse_spec, split_spec_list, technique_names
from .viewer.server import run_viewer


def _parse_sets(items) -> dict:
    out = {}
    for it in items or []:
        if "=" not in it:
            raise DyngiError(f"--set expects key=value, got '{it}'")
        k, v = it.split("=", 1)
        out[k.strip()] = v.strip()
    return out


def _positive(name):
    def conv(text):
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be an integer, got '{text}'") from None
        if v < 1:
            raise argparse.ArgumentTypeError(f"{name} must be >= 1, got {v}")
        return v
    return conv


def _fps(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--fps must be a number of frames per second, got '{text}'") from None
    if not (v == v and 0 < v < 1e6):
        raise argparse.ArgumentTypeError(f"--fps must be a positive number of frames per second, got '{text}'")
    return v


def _scene_opts(args) -> dict:
    """``--fps``, ``--camera``, ``--animation``, ``--loop`` as :func:`~dyngi.scene.load_scene` keywords."""
    return {"fps": getattr(args, "fps", None), "camera": getattr(args, "camera", None),
            "animation": getattr(args, "animation", None), "loop": getattr(args, "loop", None) or None}


def _load(args):
    return load_scene(args.scene, **_scene_opts(args))


def _frame_list(text, frames):
    if text is None:
        return None
    try:
        out = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise DyngiError(f"--grid-frames must be comma-separated frame indices, got '{text}'") from None
    bad = [i for i in out if not 0 <= i < frames]
    if bad:
        raise DyngiError(f"--grid-frames: frame {bad[0]} is outside 0..{frames - 1}")
    return out


def cmd_scenes(args) -> int:
    names = builtin_names()
    width = max(len(n) for n in names)
    for n in names:
        e = BUILTINS[n]
        sc = make_builtin(n)
        loop = any(getattr(getattr(a, tr, None), "loop", False) for a in sc.animators
                   for tr in ("translate", "angle", "track", "direction"))
        timing = (f"{sc.duration:g} s at {sc.fps:g} fps ({int(round(sc.duration * sc.fps))} frames"
                  + (", loops" if loop else "") + ")") if sc.is_animated else "static"
        print(f"{n:<{width}}  {e.description}")
        print(f"{'':<{width}}    {timing}; {len(sc.meta.emitters)} emitter(s); probe grid "
              + "x".join(map(str, sc.meta.probe_counts)))
        if e.stands_for:
            print(f"{'':<{width}}    stands for: {e.stands_for}")
    return 0


def cmd_techniques(args) -> int:
    print("Name a technique with settings as a spec NAME[:KEY=VALUE...], e.g. ddgi:hysteresis=0.9\n")
    for n in technique_names():
        cls = REGISTRY[n]
        print(f"{n}: {cls.description}")
        for k, p in cls.PARAMS.items():
            extra = f" (one of {', '.join(map(str, p.choices))})" if p.choices else ""
            if p.min is not None or p.max is not None:
                lo = "" if p.min is None else f"{p.min:g} <= "
                hi = "" if p.max is None else f" <= {p.max:g}"
                extra += f" [{lo}{k}{hi}]"
            print(f"    {k} = {p.default!r}  {p.doc}{extra}")
    return 0


def _setup(args):
    backend.set_device(args.device)


def cmd_render(args) -> int:
    _setup(args)
    params = _parse_sets(args.set)
    spec = parse_spec(args.technique)             # the one parse; passed down as a TechniqueSpec
    if args.spp is not None:
        if "spp" not in get_technique(spec.name).PARAMS:
            raise DyngiError(f"--spp does not apply to technique '{spec.name}' (it has no 'spp' "
                             "parameter; see 'dyngi techniques')")
        params.setdefault("spp", args.spp)
    spec = spec.with_settings(params)             # --set checked against the technique's parameters here
    res = parse_res(args.res) if args.res is not None else None
    with scene_options(**_scene_opts(args)):
        summary = render_to_dir(args.scene, spec, args.out, frames=args.frames, res=res,
                                seed=args.seed, t0=args.t0, quiet=args.quiet, denoise=args.denoise)
    w, h = summary["res"]
    print(f"wrote {summary['frames']} frame(s) of '{summary['scene']}' at {w}x{h} with '{args.technique}' to "
          f"{args.out} ({summary['mean_ms']:.1f} ms/frame, {summary['mean_rays'] / 1e6:.2f} Mrays/frame)")
    return 0


def cmd_reference(args) -> int:
    _setup(args)
    scene = _load(args)
    res = parse_res(args.res)
    kw = {} if args.spp is None else {"spp": args.spp}

    depth = scene_max_depth(scene) if args.ref_depth is None else args.ref_depth
    if _cluster_spec(args) != "local":
        return _reference_on_cluster(args, scene, res, depth, kw)
    bar = None
    if not args.quiet:
        from tqdm import tqdm
        bar = tqdm(total=args.frames, desc=f"reference {scene.name}", unit="frame", file=sys.stderr)
    ind = None
    if args.indirect:   # the indirect-only reference that 'dyngi compare --indirect' reads

        fn = indirect_reference_fn()
        ind = lambda r: fn(scene, r["time"], res, kw.get("spp", DEFAULT_REF_SPP), depth)  # noqa: E731

    def progress(rec):
        if ind is not None:
            ind(rec)
        if bar is not None:
            bar.update(1)
    recs = fill_reference_cache(scene, args.frames, res, max_depth=depth, progress=progress, halves=True, **kw)
    if bar is not None:
        bar.close()
    hits = sum(r["cached"] for r in recs)
    print(f"reference cache holds {len(recs)} frame(s) of '{scene.name}' at {res[0]}x{res[1]} "
          f"({hits} already cached)")
    return 0


def _cluster_spec(args) -> str:
    """``--cluster``, else ``$DYNGI_CLUSTER``, else ``local`` (validated)."""
    return resolve_cluster(getattr(args, "cluster", None))


def _cluster_run(args, fn):
    """``fn()`` with the executor of ``--cluster`` as the current one (:mod:`dyngi.experiments.cluster`);
    returns ``(fn's result, 1 if tasks failed after retries (printed) else 0)``."""
    ex = cluster.make_executor(getattr(args, "cluster", None), quiet=getattr(args, "quiet", False))
    try:
        with cluster.use(ex):
            out = fn()
    finally:
        ex.close()
    return out, cluster.report_failures(ex)


def _reference_on_cluster(args, scene, res, depth, kw) -> int:
    """``dyngi reference --cluster ...``: frames and spp chunks as tasks (reference_job)."""
    def job():
        ex = cluster.current()
        prog = cluster.Progress(0, f"reference {scene.name} ({ex.kind}, {ex.workers} workers)", args.quiet)
        try:
            return reference_job(scene, args.frames, res, kw.get("spp", DEFAULT_REF_SPP), depth, executor=ex,
                                 halves=True, chunks=args.chunks, progress=prog, indirect=args.indirect,
                                 source=cluster.scene_ref(args.scene))
        finally:
            prog.close()
    recs, bad = _cluster_run(args, job)
    hits = sum(r["cached"] for r in recs)
    done = sum(not r["failed"] for r in recs)
    print(f"reference cache holds {done} of {len(recs)} frame(s) of '{scene.name}' at {res[0]}x{res[1]} "
          f"({hits} already cached)")
    return bad


def _report_failures(out) -> int:
    """Print the techniques that returned NaN/Inf pixels (from summary.json, or merged from the
    sub-folders' when the top level has none); 1 if any, else 0."""
    try:
        with open(os.path.join(out, "summary.json")) as f:
            techs = json.load(f).get("techniques")
    except (OSError, ValueError):
        techs = None
    if techs is None:
        techs = merged_techniques(out)
    bad = [f"{t} ({s['nonfinite_pixels']} NaN/Inf pixels in {s['nonfinite_frames']} frame(s))"
           for t, s in techs.items() if s.get("failed")]
    if bad:
        print(f"dyngi: FAILED: {'; '.join(bad)}; their metrics are NaN (see summary.md)", file=sys.stderr)
        return 1
    return 0


def cmd_compare(args) -> int:
    _setup(args)
    techs = parse_specs(split_spec_list(args.techniques))      # parsed once, here; passed down
    with scene_options(**_scene_opts(args)):
        return _compare(args, techs)


def _compare(args, techs) -> int:
    out, bad = _cluster_run(args, lambda: run_compare(
        args.scene, techs, args.out, frames=args.frames, res=parse_res(args.res),
        budget=args.budget, seed=args.seed, ref_spp=args.ref_spp, quiet=args.quiet,
        params=_parse_sets(args.set),
        metrics=[m.strip() for m in args.metrics.split(",") if m.strip()],
        grid_frames=_frame_list(args.grid_frames, args.frames),
        ref_depth=args.ref_depth, indirect=args.indirect, denoise=args.denoise,
        reference=args.reference, untextured=args.untextured, tracked=not args.no_tracked))
    print(f"wrote comparison to {out} (open {os.path.join(out, 'report.html')})")
    return max(_report_failures(out), bad)


def cmd_sweep(args) -> int:
    _setup(args)
    out = args.out or os.path.join("out", "sweep", f"{args.technique}-"
                                   f"{os.path.splitext(os.path.basename(args.scene))[0]}")
    with scene_options(**_scene_opts(args)):
        return _sweep(args, out)


def _sweep(args, out) -> int:
    out, bad = _cluster_run(args, lambda: run_sweep(
        args.technique, args.scene, args.grid, args.seeds, out, frames=args.frames, res=parse_res(args.res),
        ref_spp=args.ref_spp, ref_depth=args.ref_depth,
        metrics=[m.strip() for m in args.metrics.split(",") if m.strip()], params=_parse_sets(args.set),
        quiet=args.quiet))
    print(f"wrote sweep to {out} (open {os.path.join(out, 'report.html')})")
    return bad


def cmd_reproduce(args) -> int:
    if args.list:
        for n in experiment_names():
            print(f"{n}: {EXPERIMENTS[n].description}")
        return 0

    if not args.name:
        raise DyngiError("name an experiment, e.g. 'dyngi reproduce ddgi --quick'; registered experiments: "
                         + ", ".join(experiment_names()))
    get_experiment(args.name)
    out = args.out or os.path.join("out", "reproduce", args.name + ("-smoke" if args.smoke else
                                                                      "-quick" if args.quick else ""))
    if args.name == "ddgi-resampling" and args.only is not None and not args.table:
        return _resampling_scenes(args, out)
    if args.only is not None or args.table:
        return _smcir_parts(args, out)
    _setup(args)
    opts = _reference_options(args)
    if opts:       # --reference / --untextured / --no-tracked: only experiments whose function takes them

        exp = get_experiment(args.name)
        takes = inspect.signature(exp.fn).parameters
        if not all(k in takes for k in opts):
            raise DyngiError(f"experiment '{args.name}' takes no --reference/--untextured/--no-tracked; "
                             "experiments that do: smcir")
        check_writable(out)

        with smoke_size(args.name) if args.smoke else contextlib.nullcontext():
            out, bad = _cluster_run(args, lambda: exp.fn(os.path.abspath(out), args.quick or args.smoke, args.quiet,
                                                         **opts))
    else:
        out, bad = _cluster_run(args, lambda: run_experiment(args.name, out, quick=args.quick, quiet=args.quiet,
                                                             smoke=args.smoke))
    _print_verdicts(out)
    print(f"wrote reproduction '{args.name}' to {out} (open {os.path.join(out, 'report.html')})")
    return max(_report_failures(out), bad)


def _print_verdicts(out: str) -> None:
    """One line per claim of ``out/summary.json``: its key, where in the paper, the computed verdict word and
    its conditions (dyngi.experiments.claims; nothing prints a verdict that was not computed)."""
    try:
        with open(os.path.join(out, "summary.json")) as f:
            claims = json.load(f).get("claims", [])
    except (OSError, ValueError):
        return
    for c in claims:
        why = f" ({'; '.join(c['conditions'])})" if c.get("conditions") else ""
        print(f"  {c['claim']} ({c['where']}): {c['verdict']}{why}")


def _resampling_scenes(args, out) -> int:
    """``dyngi reproduce ddgi-resampling --only SCENE ...``: these scenes of Table 1, each saved in ``out`` as it
    ends (skipped when saved before); the run without ``--only`` then reports them all."""
    check_writable(out)
    _setup(args)
    resampling_run_only(os.path.abspath(out), args.only, quick=args.quick, quiet=args.quiet,
             on_scene=lambda sc, path: print(f"{sc}: {path}", flush=True))
    print(f"finished {len(args.only)} ddgi-resampling scene(s) in {out}; 'dyngi reproduce ddgi-resampling"
          f"{' --quick' if args.quick else ''} --out {out}' writes the report (running the scenes not there yet)")
    return 0


def _smcir_parts(args, out) -> int:
    """``dyngi reproduce smcir --only SEQ:SEEDS ...`` (some runs of the full reproduction, resumable) and
    ``--table`` (Table 1 / Table 2 from the runs finished in ``out``)."""
    if args.name != "smcir":
        raise DyngiError(f"--only and --table belong to the smcir reproduction (--only also to ddgi-resampling), "
                         f"not '{args.name}'")
    if args.only is not None and args.table:
        raise DyngiError("--only runs, --table reads: give one of them")
    if args.table:
        md = table_markdown(out)
        if not md:
            raise DyngiError(f"no finished smcir runs (SEQ/seedN/figures.json) under '{out}'")
        print(md)
        return 0

    pairs = parse_pairs(args.only)
    opts = _reference_options(args)
    check_reference(opts.get("reference", "path"), True)
    check_writable(out)
    _setup(args)
    run_pairs(out, pairs, quick=args.quick, quiet=args.quiet, **opts,
              on_pair=lambda rec: print(json.dumps(rec), flush=True))
    print(f"finished {len(pairs)} smcir run(s) in {out}; 'dyngi reproduce smcir --out {out} --table' prints the "
          f"tables, 'dyngi reproduce smcir --out {out}' the report once every run is there")
    return 0


def _reference_options(args) -> dict:
    """The reference options given on the command line (SMC-IR Sec. 5.2 / 5.4), as keyword arguments."""
    opts = {}
    if getattr(args, "reference", None) is not None:
        opts["reference"] = args.reference
    if getattr(args, "untextured", False):
        opts["untextured"] = True
    if getattr(args, "no_tracked", False):
        opts["tracked"] = False
    return opts


def _cluster_flag(s):
    s.add_argument("--cluster", default=None, metavar="WHERE",
                   help="where the job's independent tasks run: local (this process, the default), auto (a "
                        "running Ray cluster, else a local one sized to this machine) or ray://HOST:PORT; "
                        "default $DYNGI_CLUSTER; needs pip install 'dyngi[ray]' (see docs/cluster.md)")


def _reference_flags(s, default):
    s.add_argument("--reference", default=default, metavar="KIND",
                   help="path (default: path-traced) or clamped (clamped path tracing, SMC-IR Sec. 5.4; "
                        "indirect only, clamp = the VPL techniques' clamp_distance)")
    s.add_argument("--untextured", action="store_true",
                   help="replace every texture by its mean colour for the techniques and the reference "
                        "(SMC-IR Sec. 5)")
    s.add_argument("--no-tracked", action="store_true",
                   help="no per-pixel reference for the 8 tracked pixels (the image reference stands in)")


def cmd_probe_view(args) -> int:
    _setup(args)
    res = parse_res(args.res)
    check_writable(args.out)
    scene = _load(args)
    tech = create_technique(args.technique, scene, _parse_sets(args.set))
    if not hasattr(tech, "debug_view"):
        raise DyngiError(f"technique '{args.technique}' has no probe volume to show; use ddgi, qddgi "
                         "or probes-reference")
    seq = run_sequence(scene, tech, args.frames, res, seed=args.seed, t0=args.t0)
    t = seq.times[-1]
    view = tech.debug_view(scene.camera(t), res)
    with atomic_output_dir(args.out) as tmp:
        write_png(os.path.join(tmp, "probes.png"), view)
        write_exr(os.path.join(tmp, "probes.exr"), view)
        write_png(os.path.join(tmp, "frame.png"), seq.images[-1])
    n_act = int((tech.volume.state.states != 0).sum())
    print(f"wrote {args.out}/probes.png ({n_act} of {tech.volume.n_probes} probes active; inactive ones "
          "are dark red) and frame.png")
    return 0


def _port(text):
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--port must be an integer, got '{text}'") from None
    if not 0 <= v <= 65535:
        raise argparse.ArgumentTypeError(f"--port must be in 0..65535 (0: any free port), got {v}")
    return v


def cmd_view(args) -> int:
    with scene_options(**_scene_opts(args)):
        return run_viewer(args.scene, args.techniques, host=args.host, port=args.port, res=parse_res(args.res),
                          device=args.device, ref_spp=args.ref_spp, token=not args.no_token)


def cmd_demo(args) -> int:
    _setup(args)
    res = parse_res(args.res) if args.res else None
    if args.classic:     # the former demo: ddgi and path on the animated Cornell box

        names = technique_names()
        techs = [t for t in ("ddgi", "path") if t in names]
        out = run_compare("cornell-moving-light", techs, args.out, frames=args.frames or 16, res=res or (160, 120),
                          budget="equal-frames", seed=0, ref_spp=args.ref_spp or 256, quiet=args.quiet, params={})
        print(f"demo written to {out}: frames, video, metrics.csv, summary.md, report.html")
        with open(os.path.join(out, "summary.md")) as f:
            print(f.read())
        return _report_failures(out)

    secs = select_sections(args.sections.split(",") if args.sections else None)
    out = run_tour(args.out, "quick" if args.quick else "tour", [s.key for s in secs], quiet=args.quiet, res=res,
                   frames=args.frames, ref_spp=args.ref_spp)
    with open(os.path.join(out, "summary.json")) as f:
        summary = json.load(f)
    print(f"demo written to {out} in {summary['wall_s']:.0f} s: one section per paper, each against its baseline")
    for s in summary["sections"]:
        print(f"  {s['title']} ({s['scene']}): {s['measured']['text']}")
        for c in s.get("claims", []):      # computed from the seeds (dyngi.experiments.claims), never by hand
            why = f" ({'; '.join(c['conditions'])})" if c["conditions"] else ""
            print(f"    {c['claim']} ({c['where']}): {c['verdict']}{why}")
    print(f"open {os.path.join(out, 'report.html')}")
    prog = os.path.relpath(sys.argv[0]) if os.path.basename(sys.argv[0]) == "dyngi" else "dyngi"
    view = summary["sections"][0]["view"] if summary["sections"] else "dyngi view tunnel-gate --techniques qddgi,adgi"
    print(f"explore further in the browser: {prog}{view[len('dyngi'):]}")
    return _report_failures(out)


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump), like every other dyngi error."""

    def error(self, message):
        self.exit(2, f"dyngi: error: {message} (see '{self.prog} --help')\n")


def _time(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--t0 must be a number of seconds, got '{text}'") from None
    if not (v == v and abs(v) < 1e9) or v < 0:
        raise argparse.ArgumentTypeError(f"--t0 must be a finite time >= 0 s, got '{text}'")
    return v


def _depth(text):
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--ref-depth must be an integer, got '{text}'") from None
    if v < 1 and v != -1:
        raise argparse.ArgumentTypeError(f"--ref-depth must be >= 1 or -1 (unbounded), got {v}")
    return v


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="dyngi", description="Real-time dynamic GI research on Mitsuba 3 + Dr.Jit")
    sub = p.add_subparsers(dest="cmd", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    s = sub.add_parser("scenes", help="list built-in scenes")
    s.set_defaults(fn=cmd_scenes)
    s = sub.add_parser("techniques", help="list techniques and their parameters")
    s.set_defaults(fn=cmd_techniques)

    def scene_flags(sp):
        sp.add_argument("--fps", type=_fps, default=None,
                        help="frames per second: frame i shows time i / FPS (default the scene's fps; 30 for glTF)")
        sp.add_argument("--camera", default=None, metavar="NAME",
                        help="the scene file's camera to use: a glTF camera (or its node) by name, a Mitsuba XML "
                             "sensor by id (default the first)")
        sp.add_argument("--animation", default=None, metavar="FILE",
                        help="keyframe sidecar (TOML) animating a Mitsuba XML scene (default: NAME.anim.toml "
                             "beside NAME.xml when present)")
        sp.add_argument("--loop", action="store_true",
                        help="glTF: animations wrap at the last keyframe (default: they hold it)")

    def common(sp, frames_default=1, res_default="320x240"):
        sp.add_argument("--frames", type=_positive("--frames"), default=frames_default,
                        help=f"number of frames, at the scene's fps or --fps (default {frames_default})")
        sp.add_argument("--res", default=res_default,
                        help=f"image size WxH (default {res_default})" if res_default else
                        "image size WxH (default: a scene file's film resolution; 320x240 for built-in scenes)")
        sp.add_argument("--device", default="cpu", choices=("cpu", "cuda"),
                        help="cpu: llvm_ad_rgb (default); cuda: cuda_ad_rgb on an NVIDIA GPU")
        sp.add_argument("--quiet", action="store_true", help="no progress bar")
        scene_flags(sp)

    s = sub.add_parser("render", help="render a scene with a technique")
    s.add_argument("scene", help="built-in scene name or path to a scene file")
    s.add_argument("--technique", default="path",
                   help="technique spec NAME[:KEY=VALUE...] (default path; e.g. ddgi:hysteresis=0.9; "
                        "see 'dyngi techniques')")
    s.add_argument("--spp", type=_positive("--spp"), default=None,
                   help="samples per pixel, for techniques with an 'spp' parameter (path)")
    s.add_argument("--seed", type=int, default=0, help="random seed (default 0); same seed, same EXRs")
    s.add_argument("--t0", type=_time, default=0.0,
                   help="start time in seconds (default 0; looping animations wrap, see 'dyngi scenes')")
    s.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="technique parameter, repeatable (see 'dyngi techniques')")
    s.add_argument("--denoise", action="store_true",
                   help="also write frame_NNNN_denoised.exr/.png: every frame denoised with Intel OIDN (pyoidn; our substitute for the OptiX denoiser "
                        "of the DDGI Resampling paper), fed with albedo and normal AOVs of the primary hits")
    s.add_argument("--out", required=True, help="output folder (created; files in it are replaced)")
    common(s, res_default=None)
    s.set_defaults(fn=cmd_render)

    s = sub.add_parser("reference", help="fill the ground-truth cache (Mitsuba's path integrator)")
    s.add_argument("scene")
    s.add_argument("--spp", type=_positive("--spp"), default=None)
    s.add_argument("--indirect", action="store_true", help="also the indirect-only reference")
    s.add_argument("--ref-depth", type=_depth, default=None,
                   help="reference max depth (default: the scene's own max depth, 12 for built-in scenes)")
    _cluster_flag(s)
    s.add_argument("--chunks", type=_positive("--chunks"), default=None,
                   help="on a cluster: split each frame's samples into this many tasks (default: about two "
                        "tasks per worker); the merged image equals the serial one")
    common(s, res_default="160x120")
    s.set_defaults(fn=cmd_reference)

    s = sub.add_parser("compare", help="compare techniques against the reference")
    s.add_argument("scene")
    s.add_argument("--techniques", required=True,
                   help="comma-separated specs NAME[:KEY=VALUE...], e.g. ddgi,ddgi:hysteresis=0.9,path:spp=4; "
                        "each is labelled as typed")
    s.add_argument("--budget", default="equal-frames", choices=("equal-frames", "equal-rays", "equal-time"))
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--ref-spp", type=_positive("--ref-spp"), default=None,
                   help="reference samples per pixel (default 1024; rendered as two independent halves whose "
                        "difference estimates the reference's own noise)")
    s.add_argument("--ref-depth", type=_depth, default=None,
                   help="reference max depth (default: the scene's own max depth, 12 for built-in scenes)")
    s.add_argument("--indirect", action="store_true",
                   help="compare indirect-only images against an indirect-only reference")
    _reference_flags(s, "path")
    s.add_argument("--denoise", action="store_true",
                   help="also report every technique as <spec>+denoise: its frames denoised with Intel OIDN (pyoidn; our substitute for the OptiX denoiser "
                        "of the DDGI Resampling paper), fed with albedo and normal AOVs of the primary hits")
    s.add_argument("--grid-frames", default=None, metavar="I,J,...",
                   help="frames shown in the image grids (default: the middle and the last)")
    s.add_argument("--metrics", default="mse,relmse,mape,flip,ssim",
                   help="comma-separated metrics (FLIP is the slow one)")
    s.add_argument("--set", action="append", metavar="TECH.KEY=VALUE",
                   help="technique parameter for every spec of TECH (or KEY=VALUE for every technique that has "
                        "KEY); a spec's own settings win")
    s.add_argument("--out", required=True)
    _cluster_flag(s)
    common(s, frames_default=30, res_default="160x120")
    s.set_defaults(fn=cmd_compare)

    s = sub.add_parser("sweep", help="a technique's error and time over a grid of its parameters and seeds")
    s.add_argument("technique", help="technique name (see 'dyngi techniques')")
    s.add_argument("scene", help="built-in scene name or path to a scene file")
    s.add_argument("--grid", action="append", metavar="KEY=A,B,...",
                   help="a parameter and its values, repeatable; the sweep runs every combination")
    s.add_argument("--seeds", type=_positive("--seeds"), default=1,
                   help="seeds 0..N-1 per grid point (default 1)")
    s.add_argument("--set", action="append", metavar="KEY=VALUE", help="fixed technique parameter, repeatable")
    s.add_argument("--ref-spp", type=_positive("--ref-spp"), default=None,
                   help="reference samples per pixel (default 1024, as for compare)")
    s.add_argument("--ref-depth", type=_depth, default=None,
                   help="reference max depth (default: the scene's own max depth, 12 for built-in scenes)")
    s.add_argument("--metrics", default="mse,relmse,mape,flip,ssim", help="comma-separated metrics")
    s.add_argument("--out", default=None, help="output folder (default out/sweep/TECHNIQUE-SCENE)")
    _cluster_flag(s)
    common(s, frames_default=30, res_default="160x120")
    s.set_defaults(fn=cmd_sweep)

    s = sub.add_parser("reproduce", help="a paper's comparison on the analog scenes, beside its published figures")
    s.add_argument("name", nargs="?", help="experiment name (see --list)")
    s.add_argument("--list", action="store_true", help="list the registered experiments")
    s.add_argument("--quick", action="store_true", help="a small version (minutes on 2 CPU cores)")
    s.add_argument("--smoke", action="store_true",
                   help="the --quick code path at a tiny size (seconds): checks that it runs, measures nothing")
    s.add_argument("--out", default=None, help="output folder (default out/reproduce/NAME[-quick])")
    s.add_argument("--device", default="cpu", choices=("cpu", "cuda"),
                   help="cpu: llvm_ad_rgb (default); cuda: cuda_ad_rgb on an NVIDIA GPU")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.add_argument("--only", nargs="+", default=None, metavar="SEQ[:SEEDS]",
                   help="smcir: run only these (sequence, seed) runs, e.g. maze:0,1 atrium-sun (seed 0); "
                        "ddgi-resampling: only these scenes, e.g. room-door; each is saved in --out as it ends and "
                        "skipped when saved before (split a full run over processes)")
    s.add_argument("--table", action="store_true",
                   help="smcir: print Table 1 and Table 2 (Markdown) from the runs finished in --out; runs nothing")
    _reference_flags(s, None)
    _cluster_flag(s)
    s.set_defaults(fn=cmd_reproduce)

    s = sub.add_parser("probe-view", help="render a technique's probes as spheres shaded by their irradiance")
    s.add_argument("scene")
    s.add_argument("--technique", default="ddgi", help="ddgi (default), qddgi or probes-reference")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--t0", type=_time, default=0.0, help="start time in seconds")
    s.add_argument("--set", action="append", metavar="KEY=VALUE", help="technique parameter")
    s.add_argument("--out", required=True, help="output folder (probes.png, probes.exr, frame.png)")
    common(s, frames_default=1, res_default="320x240")
    s.set_defaults(fn=cmd_probe_view)

    s = sub.add_parser("view", help="interactive browser viewer: camera, animation, techniques side by side, "
                                    "probes, live stats, error view")
    s.add_argument("scene", help="built-in scene name or path to a scene file")
    s.add_argument("--techniques", default="ddgi",
                   help="comma-separated specs offered on the page (default ddgi); the first is shown, a second "
                        "beside it in the split view")
    s.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only)")
    s.add_argument("--port", type=_port, default=None,
                   help="port (default 8765, or a free one when it is taken; 0: any free port)")
    s.add_argument("--res", default="320x180", help="render size WxH (default 320x180)")
    s.add_argument("--ref-spp", type=_positive("--ref-spp"), default=128,
                   help="samples per pixel of the error view's reference (default 128)")
    s.add_argument("--device", default="cpu", choices=("cpu", "cuda"),
                   help="cpu: llvm_ad_rgb (default); cuda: cuda_ad_rgb on an NVIDIA GPU")
    s.add_argument("--no-token", action="store_true",
                   help="serve without the random token in the address (loopback --host only; the websocket "
                        "still refuses other sites' pages)")
    scene_flags(s)
    s.set_defaults(fn=cmd_view)

    s = sub.add_parser("demo", help="the main job: a short tour of the five papers' techniques, each on its analog "
                                    "scene against its baseline, in one report.html")
    s.add_argument("--out", default="out/demo")
    s.add_argument("--quick", action="store_true",
                   help="a tiny tour (32x18, 2 frames, 4-spp references): the set-up and the report, not the claims")
    s.add_argument("--sections", default=None, metavar="A,B,...",
                   help="only these sections (adgi, isddgi, ddgi-resampling, smcir, vlc, cdq; default all)")
    s.add_argument("--classic", action="store_true",
                   help="the former demo instead: ddgi and path on cornell-moving-light (16 frames, 160x120, 256 spp)")
    s.add_argument("--ref-spp", type=_positive("--ref-spp"), default=None,
                   help="ground-truth spp (default 64 for the tour, 4 with --quick, 256 with --classic)")
    s.add_argument("--frames", type=_positive("--frames"), default=None,
                   help="frames per section (default 8; 2 with --quick; 16 with --classic)")
    s.add_argument("--res", default=None, help="image size WxH (default 96x54; 32x18 with --quick; 160x120 with "
                                               "--classic); the tour's VLC and CDQ sections run at twice it")
    s.add_argument("--device", default="cpu", choices=("cpu", "cuda"),
                   help="cpu: llvm_ad_rgb (default); cuda: cuda_ad_rgb on an NVIDIA GPU")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.set_defaults(fn=cmd_demo)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.fn(args)
    except DyngiError as e:
        print(f"dyngi: error: {e}", file=sys.stderr)
        return 2
    except BrokenPipeError:   # output piped into e.g. `head`
        try:
            sys.stdout = open(os.devnull, "w")
        except OSError:
            pass
        return 0
    except KeyboardInterrupt:
        print("dyngi: interrupted; nothing half-written was kept", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
