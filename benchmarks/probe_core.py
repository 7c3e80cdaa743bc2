"""Probe-core benchmarks: prints markdown tables.

1. ``--cost``: the ``ddgi`` probe update on the Cornell box (default grid, 256 rays per probe) with
   the BLAS matrix estimator and with the Dr.Jit scatter estimator: median update and blend times.
   Run it once with the code before the refactor on ``PYTHONPATH`` (``--before``: no estimator
   parameter there) to compare the update time.
2. ``--bias``: the perceptual (gamma 5) blend's bias at few rays per probe. A probe volume under
   an analytic environment ``L(w) = 0.2 + 4 max(0, w.s)^16`` (a bright window; the truth of every
   texel is known: the cosine-weighted mean of ``L``, computed with 2^17 spherical-Fibonacci
   directions), blended for 400 frames with hysteresis 0.97 and a fresh random rotation per frame;
   the time average of the stored texels over the last 250 frames against the truth, for gamma 5 and
   gamma 1 (linear). No tracing: the radiance of every ray is ``L`` of its direction.

Usage: ``python benchmarks/probe_core.py [--cost] [--bias] [--before] [--frames F]``.

Recorded in ``docs/techniques/ddgi.md`` ("Low bias of the perceptual (gamma 5) blend"), beside the command,
resolution, seeds and machine load of each run.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from dyngi.backend import mi


def update_cost(frames: int, before: bool) -> list:
    from dyngi.scene import load_scene
    from dyngi.techniques.base import Frame, create_technique
    from dyngi.probes.pipeline import UPDATE_STAGES
    sc = load_scene("cornell-static")
    res = (160, 90)
    rows = []
    for est in (["(before)"] if before else ["matrix", "scatter"]):
        params = {} if before else {"estimator": est}
        tech = create_technique("ddgi", sc, params)
        cam = sc.camera(0.0)
        ups, blends = [], []
        for f in range(frames + 3):
            r = tech.step(Frame(f, 0.0, cam, res, seed=0))
            ms = r.stats["ms"]
            if f >= 3:
                ups.append(sum(ms.get(k, 0.0) for k in UPDATE_STAGES))
                blends.append(ms.get("blend", 0.0))
        probes = r.stats.get("probes_traced")
        rows.append((f"ddgi update, Cornell box, {probes} probes x {r.stats['rays_per_probe']} rays, "
                     f"estimator {est}", f"{np.median(ups):.1f} ms", f"blend {np.median(blends):.1f} ms"))
    return rows


def environment(d: np.ndarray) -> np.ndarray:
    s = np.array([0.3, 0.5, 0.81])
    s /= np.linalg.norm(s)
    return 0.2 + 4.0 * np.maximum(d @ s, 0.0) ** 16


def gamma_bias(frames: int) -> list:
    from dyngi.probes import HysteresisBlend, ProbeGrid, ProbeVolume, UniformSFDirections
    from dyngi.probes.trace import ProbeRayResults
    from dyngi.probes.arrays import upload
    from dyngi.sampling.fibonacci import spherical_fibonacci_np
    from dyngi.sampling.octahedral import texel_directions
    from dyngi.scene import load_scene

    sc = load_scene("furnace")
    T = 8
    big = spherical_fibonacci_np(1 << 17)
    Lb = environment(big)
    tdirs = texel_directions(T)[1:-1, 1:-1].reshape(-1, 3)
    c = np.maximum(big @ tdirs.T, 0.0)
    truth = (c.T @ Lb) / c.sum(0)                    # E/pi per interior texel
    rows = []
    for n in (8, 16, 32, 64, 256):
        out = []
        for gamma in (5.0, 1.0):
            vol = ProbeVolume(ProbeGrid.from_scene(sc, (2, 2, 2)), T, 8)
            ids = np.arange(vol.n_probes, dtype=np.uint32)
            dirs_of = UniformSFDirections(n)
            b = HysteresisBlend(0.97, irradiance_gamma=gamma, brightness_threshold=1e30)
            acc, k = 0.0, 0
            for f in range(frames):
                plan = dirs_of.plan(f, 0, ids)
                L = np.tile(environment(plan.shared_directions).astype(np.float32), len(ids))
                d = upload(L)
                b.update(vol, ProbeRayResults(mi.Color3f(d, d, d), upload(np.ones_like(L)), plan))
                if f >= frames - 250:
                    acc = acc + vol.state.irradiance[:, 1:-1, 1:-1, 0].reshape(len(ids), -1).mean(0)
                    k += 1
            rel = (acc / k - truth) / truth
            out.append((float(np.mean(rel)), float(np.min(rel))))
        rows.append((f"{n} rays/probe", f"gamma 5: mean {100 * out[0][0]:+.2f}% (worst texel {100 * out[0][1]:+.1f}%)",
                     f"gamma 1: mean {100 * out[1][0]:+.2f}% (worst texel {100 * out[1][1]:+.1f}%)"))
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cost", action="store_true")
    ap.add_argument("--bias", action="store_true")
    ap.add_argument("--before", action="store_true", help="the code before the refactor (no estimator parameter)")
    ap.add_argument("--frames", type=int, default=12, help="timed frames per estimator (--cost)")
    a = ap.parse_args()
    rows = []
    if a.cost or not a.bias:
        rows += update_cost(a.frames, a.before)
    if a.bias:
        rows += gamma_bias(400)
    print("| what | result | note |\n|---|---|---|")
    for r in rows:
        print("| " + " | ".join(r) + " |")


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"\n({time.perf_counter() - t0:.0f} s)")
