"""Shared helpers for the benchmark scripts: timing and raw ray-tracing throughput."""
from __future__ import annotations

import os
import subprocess
import time

from dyngi.backend import dr, mi

SHARED_SCENES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "..", "shared", "scenes")


def shared_scene(rel: str) -> str | None:
    p = os.path.normpath(os.path.join(SHARED_SCENES, rel))
    return p if os.path.exists(p) else None


def uptime() -> str:
    """The machine's load (``uptime``), printed beside every timing."""
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip()
    except OSError:
        return "(uptime unavailable)"


def parse_settings(text: str | None) -> dict:
    """``'k=v,k2=v2'`` as a dict of strings (technique parameters from a benchmark's command line)."""
    out = {}
    for item in (text or "").split(","):
        if item.strip():
            k, _, v = item.partition("=")
            out[k.strip()] = v.strip()
    return out


def best_of(fn, repeats: int = 3, warmup: int = 1) -> float:
    """Minimum wall time (s) of ``fn()`` over ``repeats`` runs after ``warmup`` runs."""
    for _ in range(warmup):
        fn()
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        dr.sync_thread()
        ts.append(time.perf_counter() - t0)
    return min(ts)


def random_rays(mi_scene, n: int, seed: int = 0) -> "mi.Ray3f":
    """Incoherent rays: origins uniform in the scene's bounding box, directions uniform on the sphere."""
    bb = mi_scene.bbox()
    rng = mi.PCG32(n, seed)
    o = bb.min + (bb.max - bb.min) * mi.Vector3f(rng.next_float32(), rng.next_float32(), rng.next_float32())
    d = mi.warp.square_to_uniform_sphere(mi.Point2f(rng.next_float32(), rng.next_float32()))
    ray = mi.Ray3f(o, d)
    dr.eval(ray)
    return ray


def raw_rays_per_second(mi_scene, n: int = 1 << 21) -> dict:
    """Throughput of Mitsuba's full ``ray_intersect`` and ``ray_intersect_preliminary`` on random rays."""
    ray = random_rays(mi_scene, n)

    def full():
        si = mi_scene.ray_intersect(ray)
        dr.eval(si.t, si.n, si.p, si.uv)

    def prelim():
        pi = mi_scene.ray_intersect_preliminary(ray)
        dr.eval(pi.t, pi.prim_index)

    return {"full": n / best_of(full), "preliminary": n / best_of(prelim)}


def md_table(rows: list[dict]) -> str:
    keys = list(rows[0].keys())
    out = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for r in rows:
        out.append("| " + " | ".join(f"{v:.3g}" if isinstance(v, float) else str(v) for v in r.values()) + " |")
    return "\n".join(out)
