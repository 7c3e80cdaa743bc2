"""Error vs wall time: dyngi's ``path`` (progressive) against Mitsuba's ``path`` integrator.

Same scene (``cornell-static``), resolution, ``max_depth`` (12) and
``rr_depth`` (5) for both; the error is relMSE (dyngi.metrics) against a
high-spp reference by Mitsuba's ``path`` (``--ref-spp``, default 4096, from
the reference cache; rendered once if missing).

* dyngi: the ``path`` technique with ``--spp`` samples per frame, stepped over
  static frames so it accumulates; after every frame the wall time of all
  ``step`` calls so far (each returns a host image) and the relMSE of the
  accumulated image. A throwaway instance runs first, so JIT compilation is
  not counted.
* Mitsuba: ``mi.render`` at 1, 2, 4, ... spp (independent renders, the image
  copied to the host); each spp is rendered once with another seed first, so
  JIT compilation is not counted either.

Printed: relMSE of both at the time points (``--times``, log-log interpolation
along each curve; nan before a curve's first sample), and time to equal error (:func:`dyngi.metrics.time_to_error`)
with the targets taken as dyngi's error at those time points; ratio > 1 means
Mitsuba needs longer. The reference's own relMSE (about relMSE(1 spp) /
ref_spp) is a floor under both curves; it is printed too.

Usage: python benchmarks/convergence.py [--res 160x120] [--spp 1] [--times 0.1,0.3,1,3] [--ref-spp 4096]

Recorded in ``docs/techniques/path.md`` ("Convergence against Mitsuba"), beside the command, resolution, seeds
and machine load of each run.
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from common import md_table
from dyngi.backend import device_info, dr, mi
from dyngi.experiments.references.path import RR_DEPTH, cached_reference
from dyngi.metrics import relmse, time_to_error
from dyngi.scene import load_scene
from dyngi.techniques.base import Frame, create_technique

SCENE = "cornell-static"
MAX_DEPTH = 12


def dyngi_curve(scene, res, spp: int, t_max: float, seed: int = 7):
    """(cumulative seconds, relMSE) after each frame of the progressive ``path`` technique."""
    cam = scene.camera(0.0)

    def make():
        return create_technique("path", scene, {"spp": spp, "max_depth": MAX_DEPTH, "rr_depth": RR_DEPTH,
                                                "progressive": True})

    warm = make()  # compiles the first-frame and the accumulation kernels
    for i in range(3):
        warm.step(Frame(index=i, time=0.0, camera=cam, res=res, seed=seed + 1, static=i > 0))
    tech = make()
    times, images = [], []
    total = 0.0
    i = 0
    while total < t_max:
        frame = Frame(index=i, time=0.0, camera=cam, res=res, seed=seed, static=i > 0)
        t0 = time.perf_counter()
        img = tech.step(frame).image
        total += time.perf_counter() - t0
        times.append(total)
        images.append(img)
        i += 1
    return np.array(times), images


def mitsuba_curve(scene, res, t_max: float, seed: int = 7):
    """(seconds, image) of independent ``mi.render`` calls at 1, 2, 4, ... spp until one takes ``t_max``."""
    integrator = mi.load_dict({"type": "path", "max_depth": MAX_DEPTH, "rr_depth": RR_DEPTH})
    cam = scene.camera(0.0)
    w, h = res
    times, images, spps = [], [], []
    spp = 1
    while True:
        sensor = cam.to_sensor(res, spp)

        def render(s):
            img = mi.render(scene.mi_scene, sensor=sensor, integrator=integrator, seed=s, spp=spp)
            return np.asarray(img, dtype=np.float32).reshape(h, w, -1)[..., :3]

        render(seed + 1000)  # warm-up: compile for this spp
        dr.sync_thread()
        t0 = time.perf_counter()
        img = render(seed)
        dt = time.perf_counter() - t0
        times.append(dt)
        images.append(img)
        spps.append(spp)
        if dt >= t_max:
            break
        spp *= 2
    return np.array(times), images, spps


def at_time(times, errors, t: float) -> float:
    """Error at time ``t`` by log-log interpolation along the curve (NaN outside it)."""
    times, errors = np.asarray(times), np.asarray(errors)
    if t < times[0] or t > times[-1]:
        return float("nan")
    order = np.argsort(times)
    return float(np.exp(np.interp(np.log(t), np.log(times[order]), np.log(errors[order]))))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", default="160x120")
    ap.add_argument("--spp", type=int, default=1, help="dyngi path: samples per pixel per frame")
    ap.add_argument("--times", default="0.1,0.3,1,3", help="time points in seconds")
    ap.add_argument("--ref-spp", type=int, default=4096)
    a = ap.parse_args(argv)
    res = tuple(int(x) for x in a.res.split("x"))
    points = [float(x) for x in a.times.split(",")]
    scene = load_scene(SCENE)

    t0 = time.perf_counter()
    ref, cached = cached_reference(scene, 0.0, res, a.ref_spp, MAX_DEPTH)
    t_ref = time.perf_counter() - t0
    scene.at(0.0)

    d_times, d_images = dyngi_curve(scene, res, a.spp, max(points) * 1.05)
    d_err = np.array([relmse(x, ref) for x in d_images])
    m_times, m_images, m_spps = mitsuba_curve(scene, res, max(points) * 1.05)
    m_err = np.array([relmse(x, ref) for x in m_images])

    rows = []
    for t in points:
        ed, em = at_time(d_times, d_err, t), at_time(m_times, m_err, t)
        rows.append({"time (s)": t, "dyngi path relMSE": ed, "Mitsuba path relMSE": em,
                     "Mitsuba / dyngi error": em / ed})
    ttr = []
    for t in points:
        target = at_time(d_times, d_err, t)
        if not np.isfinite(target):   # before dyngi's first frame
            continue
        td = time_to_error(d_times, d_err, target)
        tm = time_to_error(m_times, m_err, target)
        ttr.append({"target relMSE": target, "dyngi time (s)": td, "Mitsuba time (s)": tm,
                    "Mitsuba / dyngi time": tm / td})

    spp_per_s = len(d_images) * a.spp / d_times[-1]
    print(f"device: {device_info()}")
    print(f"scene {SCENE}, {res[0]}x{res[1]}, max_depth {MAX_DEPTH}, rr_depth {RR_DEPTH}; reference: Mitsuba "
          f"path {a.ref_spp} spp ({'cached' if cached else f'rendered in {t_ref:.0f} s'}), its own relMSE "
          f"~{m_err[0] / a.ref_spp:.2g} (Mitsuba 1 spp / ref_spp)")
    print(f"dyngi path: {a.spp} spp/frame, {len(d_images)} frames in {d_times[-1]:.2f} s "
          f"({1e3 * d_times[-1] / len(d_images):.1f} ms/frame, {spp_per_s:.0f} spp/s); "
          f"Mitsuba path: spp {m_spps[0]}..{m_spps[-1]}, "
          + ", ".join(f"{s} spp {1e3 * t:.0f} ms" for s, t in zip(m_spps, m_times)))
    print()
    print(md_table(rows))
    print()
    print(md_table(ttr))
    return rows


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
