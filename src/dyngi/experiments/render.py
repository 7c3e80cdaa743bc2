"""``dyngi render``: a technique over N frames of a scene, written to a folder.

Writes ``frame_NNNN.exr`` (linear) and ``frame_NNNN.png`` (sRGB), ``video.mp4``
when more than one frame, and ``stats.json`` (per frame: per-stage ms and rays).
Deterministic: the same seed gives bit-identical EXRs on the same backend.

``technique`` is a spec ``NAME[:KEY=VALUE...]`` (``ddgi:hysteresis=0.9``); its settings win over
``params``. ``res`` None: a scene file's own film resolution, else :data:`DEFAULT_RES`.
"""
from __future__ import annotations

import os
import sys

import numpy as np

from .. import backend
from ..scene import load_scene
from ..techniques.base import TechniqueSpec, as_spec, create_technique
from .denoise import aux_buffers, denoise as oidn, require
from .io import atomic_output_dir, check_writable, tonemap_srgb, write_exr, write_json, write_mp4, write_png
from .runner import frame_rays, run_sequence

DEFAULT_RES = (320, 240)
"""Resolution of built-in scenes (and of files without a film) when none is given."""


def default_res(scene) -> tuple[int, int]:
    """A scene file's film resolution (its first sensor), else :data:`DEFAULT_RES`."""
    if getattr(scene, "source", "builtin") != "builtin":
        sensors = scene.mi_scene.sensors()
        if sensors:
            w, h = (int(v) for v in sensors[0].film().size())
            if w >= 1 and h >= 1:
                return (w, h)
    return DEFAULT_RES


def render_to_dir(scene_name: str, technique: "str | TechniqueSpec", out_dir: str, frames: int = 1, res=None,
                  seed: int = 0, params: dict | None = None, t0: float = 0.0, quiet: bool = False,
                  denoise: bool = False) -> dict:
    """Render ``frames`` frames into ``out_dir``; with ``denoise`` also ``frame_NNNN_denoised.exr/.png``
    (Intel OIDN with albedo/normal AOVs of the primary hits, :mod:`dyngi.experiments.denoise`).
    ``technique``: a :class:`TechniqueSpec` (parsed by the caller) or its text (parsed here, once)."""
    spec = as_spec(technique).with_settings(params)
    technique = spec.label
    denoise = denoise or spec.denoise
    if denoise:
        require()
    check_writable(out_dir)
    scene = load_scene(scene_name)
    tech = create_technique(spec, scene)
    res = default_res(scene) if res is None else tuple(res)
    pngs = []
    with atomic_output_dir(out_dir) as tmp:
        bar = None
        if not quiet and frames > 1:
            from tqdm import tqdm
            bar = tqdm(total=frames, desc=f"{technique} on {scene.name}", unit="frame", file=sys.stderr)

        def on_frame(i, frame, r):
            write_exr(os.path.join(tmp, f"frame_{i:04d}.exr"), r.image)
            write_png(os.path.join(tmp, f"frame_{i:04d}.png"), r.image)
            if r.indirect is not None:
                write_exr(os.path.join(tmp, f"indirect_{i:04d}.exr"), r.indirect)
            pngs.append(tonemap_srgb(r.image))
            if denoise:
                d = oidn(r.image, *aux_buffers(scene, frame.camera, res))
                write_exr(os.path.join(tmp, f"frame_{i:04d}_denoised.exr"), d)
                write_png(os.path.join(tmp, f"frame_{i:04d}_denoised.png"), d)

        seq = run_sequence(scene, tech, frames, res, seed=seed, t0=t0, progress=bar, on_frame=on_frame,
                           keep_images=False)
        if bar is not None:
            bar.close()
        if frames > 1:
            write_mp4(os.path.join(tmp, "video.mp4"), pngs, fps=scene.fps)
        stats = {
            "scene": scene.name, "technique": technique, "params": tech.params, "res": list(res),
            "seed": seed, "device": backend.device_info(),
            "frames": [{"index": i, "time": t, "wall_ms": w, **s}
                       for i, (t, w, s) in enumerate(zip(seq.times, seq.wall_ms, seq.stats))],
        }
        write_json(os.path.join(tmp, "stats.json"), stats)
    steady, steady_ms = seq.steady()
    return {"scene": scene.name, "frames": frames, "res": list(res), "mean_ms": float(np.mean(steady_ms)),
            "mean_rays": float(np.mean([frame_rays(s) for s in steady]))}
