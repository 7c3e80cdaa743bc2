"""Overhead of the evaluation harness relative to one frame, measured in one run.

Metrics and I/O must not dominate a frame. For
``cornell-moving-light`` (a new light position every frame, so nothing
accumulates) at each resolution this times, best of ``--repeats`` after a
warm-up:

* the ``path`` technique's steady-state frame (``step``, 1 spp, max_depth 12),
  the unit every other row is divided by;
* ``compute_all`` (MSE, relMSE, MAPE, HDR-FLIP, SSIM: what ``dyngi compare``
  computes per technique and frame) and each metric alone;
* ``compute_all`` and HDR-FLIP again in fresh child processes on the same
  images, with ``OMP_WAIT_POLICY`` unset (whatever dyngi does by default) and
  ``=PASSIVE``: ``flip-evaluator`` runs on its own OpenMP runtime (a vendored
  libgomp), whose default spin-then-sleep waiting stalls when the cores are
  busy (Dr.Jit's thread pool, other jobs); the variable is read when that
  library loads, so settings can only be compared across processes;
* the temporal metrics |E|, |E'| per frame (a sequence of ``--frames`` frames, divided by the count);
* writing a PNG (tone-mapped, as ``compare`` does for every frame) and an EXR (as ``render`` does);
* loading a reference from the cache (a hit: key from the scene state, EXR read, checks);
* encoding the side-by-side MP4, per frame.

Usage: python benchmarks/harness.py [--res 160x120,320x240] [--repeats 5]

Recorded in ``docs/harness.md`` ("Harness overhead against one frame"), beside the command, resolution, seeds
and machine load of each run.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from common import best_of, md_table
from dyngi.backend import device_info
from dyngi.experiments.io import tonemap_srgb, write_exr, write_mp4, write_png
from dyngi.experiments.references.path import cached_reference
from dyngi.metrics import METRICS, compute_all, flip, temporal_errors
from dyngi.scene import load_scene
from dyngi.techniques.base import Frame, create_technique

SCENE = "cornell-moving-light"
REF_SPP = 64
"""Samples of the benchmark's reference: its noise does not change the cost of any metric."""


def path_frames(scene, res, n: int, repeats: int):
    """(best ms of a steady-state ``path`` frame, the last ``n`` frames' images)."""
    tech = create_technique("path", scene, {"spp": 1})
    images, times = [], []
    for i in range(n + 1 + repeats):  # frame 0 compiles; the rest are steady state
        t = scene.frame_time(i)
        scene.at(t)
        frame = Frame(index=i, time=t, camera=scene.camera(t), res=res, seed=0, static=False)
        t0 = time.perf_counter()
        img = tech.step(frame).image
        times.append(time.perf_counter() - t0)
        images.append(img)
    return 1e3 * min(times[1:]), images[-n:]


def metrics_in_child(img, ref, repeats: int, env_extra: dict) -> tuple[float, float]:
    """Best ms of (HDR-FLIP, compute_all) on ``img``/``ref`` in a fresh process with ``env_extra`` set."""
    with tempfile.TemporaryDirectory() as d:
        np.save(os.path.join(d, "img.npy"), img)
        np.save(os.path.join(d, "ref.npy"), ref)
        env = {k: v for k, v in os.environ.items() if k not in env_extra}
        env.update({k: v for k, v in env_extra.items() if v is not None})   # None: unset
        out = subprocess.run([sys.executable, os.path.abspath(__file__), "--metrics-only", d,
                              "--repeats", str(repeats)], capture_output=True, text=True, env=env, timeout=600)
    if out.returncode != 0:
        raise RuntimeError(out.stderr)
    f, a = out.stdout.strip().splitlines()[-1].split()
    return float(f), float(a)


def metrics_only(folder: str, repeats: int) -> tuple[float, float]:
    img = np.load(os.path.join(folder, "img.npy"))
    ref = np.load(os.path.join(folder, "ref.npy"))
    return (1e3 * best_of(lambda: flip(img, ref), repeats),
            1e3 * best_of(lambda: compute_all(img, ref), repeats))


def bench(res, frames: int, repeats: int, cache_dir: str) -> dict:
    scene = load_scene(SCENE)
    w, h = res
    frame_ms, imgs = path_frames(scene, res, frames, repeats)
    refs = [cached_reference(scene, scene.frame_time(i + 1 + repeats), res, REF_SPP, cache_dir=cache_dir)[0]
            for i in range(frames)]
    img, ref = imgs[-1], refs[-1]
    ms = {"path frame (1 spp)": frame_ms}
    ms["compute_all (5 metrics)"] = 1e3 * best_of(lambda: compute_all(img, ref), repeats)
    for name, fn in METRICS.items():
        ms[f"  {name}"] = 1e3 * best_of(lambda fn=fn: fn(img, ref), repeats)
    for policy in (None, "PASSIVE"):
        f, a = metrics_in_child(img, ref, repeats, {"OMP_WAIT_POLICY": policy})
        tag = "OMP_WAIT_POLICY unset" if policy is None else f"OMP_WAIT_POLICY={policy}"
        ms[f"compute_all, fresh process, {tag}"] = a
        ms[f"  flip, fresh process, {tag}"] = f
    ms["temporal abs(E), abs(E') per frame"] = 1e3 * best_of(
        lambda: temporal_errors(np.stack(imgs), np.stack(refs)), repeats) / frames
    with tempfile.TemporaryDirectory() as d:
        ms["PNG write"] = 1e3 * best_of(lambda: write_png(os.path.join(d, "f.png"), img), repeats)
        ms["EXR write"] = 1e3 * best_of(lambda: write_exr(os.path.join(d, "f.exr"), img), repeats)
        tiles = [np.concatenate([tonemap_srgb(r), tonemap_srgb(x)], axis=1) for r, x in zip(refs, imgs)]
        ms["MP4 encode per frame"] = 1e3 * best_of(
            lambda: write_mp4(os.path.join(d, "v.mp4"), tiles, fps=scene.fps), repeats) / frames
    t_hit = scene.frame_time(frames + repeats)

    def hit():
        _, was_cached = cached_reference(scene, t_hit, res, REF_SPP, cache_dir=cache_dir)
        assert was_cached

    ms["reference cache hit"] = 1e3 * best_of(hit, repeats)
    per_frame = ms["compute_all (5 metrics)"] + ms["PNG write"] + ms["reference cache hit"] + \
        ms["temporal abs(E), abs(E') per frame"] + ms["MP4 encode per frame"]
    ms["harness per frame in compare (sum)"] = per_frame
    return ms


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", default="160x120,320x240", help="comma-separated WxH")
    ap.add_argument("--frames", type=int, default=8, help="sequence length for the temporal metric and MP4")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--metrics-only", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.metrics_only:
        print(*metrics_only(a.metrics_only, a.repeats))
        return True
    omp_policy = os.environ.get("OMP_WAIT_POLICY", "(unset)")  # before dyngi.metrics may set it
    resolutions = [tuple(int(x) for x in r.split("x")) for r in a.res.split(",")]
    results = {}
    with tempfile.TemporaryDirectory() as cache:
        for res in resolutions:
            results[res] = bench(res, a.frames, a.repeats, cache)
    rows = []
    for op in results[resolutions[0]]:
        row = {"operation": op.replace("  ", "- ")}
        for res in resolutions:
            ms = results[res]
            key = f"{res[0]}x{res[1]}"
            row[f"{key} ms"] = ms[op]
            row[f"{key} / frame"] = ms[op] / ms["path frame (1 spp)"]
        rows.append(row)
    info = device_info()
    print(f"device: {info}; scene {SCENE}; best of {a.repeats}; OMP_WAIT_POLICY at start: {omp_policy}; "
          f"load average {os.getloadavg()[0]:.1f} "
          f"on {os.cpu_count()} cores")
    print(md_table(rows))
    return rows


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
