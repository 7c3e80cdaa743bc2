"""`dyngi view` throughput: frames/s streamed to a websocket client, and technique-switch latency.

    .venv/bin/python benchmarks/viewer_fps.py [--scene cornell-moving-light] [--res 320x180] [--seconds 15]

Starts the real command (``python -m dyngi view SCENE --techniques ddgi --res RES --port 0``), connects
one websocket client as the page does (error view off, playing), counts the frames that arrive over
``--seconds`` after a 3-s warm-up, then switches technique three times and times each switch: from
sending the command to receiving the first frame of the new spec, beside that frame's own render time
(its kernel compilation) and the spec's steady frame time. Prints one Markdown block for
docs/harness.md.

Recorded in ``docs/harness.md`` ("The viewer"), beside the command, resolution, seeds and machine load of each
run.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import struct
import subprocess
import sys
import time


async def client(url: str, seconds: float, switches: list[str]):
    from websockets.asyncio.client import connect

    out = {}
    async with connect(url, max_size=2 ** 24) as ws:
        frames = []          # (arrival, header)
        stats = {}

        async def pump(until: float, stop=None):
            while time.perf_counter() < until:
                try:
                    m = await asyncio.wait_for(ws.recv(), until - time.perf_counter())
                except asyncio.TimeoutError:
                    return None
                if isinstance(m, bytes):
                    n = struct.unpack("<I", m[:4])[0]
                    h = json.loads(m[4:4 + n])
                    frames.append((time.perf_counter(), h))
                    if stop is not None and stop(h):
                        return h
                else:
                    j = json.loads(m)
                    if j.get("type") == "stats":
                        stats.setdefault(j["spec"], []).append(j)
            return None

        await pump(time.perf_counter() + 3.0)             # warm-up: compile, first frames
        n0 = len(frames)
        t0 = time.perf_counter()
        await pump(t0 + seconds)
        got = [f for f in frames[n0:] if f[1]["slot"] == "a"]
        out["fps"] = len(got) / (time.perf_counter() - t0)
        ddgi = sorted(s["wall_ms"] for s in stats.get("ddgi", [])[3:])
        enc = sorted(s["encode_ms"] for s in stats.get("ddgi", [])[3:])
        out["ddgi_ms"] = ddgi[len(ddgi) // 2] if ddgi else None
        out["encode_ms"] = enc[len(enc) // 2] if enc else None
        out["switches"] = []
        for spec in switches:
            sent = time.perf_counter()
            await ws.send(json.dumps({"type": "technique", "slot": "a", "spec": spec}))
            h = await pump(sent + 120, stop=lambda h, s=spec: h["slot"] == "a" and h["spec"] == s)
            arrived = time.perf_counter()
            await pump(arrived + 4.0)                      # a few steady frames of the new spec
            st = stats.get(spec, [])
            steady = sorted(s["wall_ms"] for s in st[2:]) if len(st) > 2 else []
            out["switches"].append({"spec": spec, "latency_ms": 1e3 * (arrived - sent) if h else None,
                                    "first_frame_ms": st[0]["first_frame_ms"] if st else None,
                                    "build_ms": st[0]["build_ms"] if st else None,
                                    "inflight_ms": out["ddgi_ms"],
                                    "steady_ms": steady[len(steady) // 2] if steady else None})
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="cornell-moving-light")
    ap.add_argument("--res", default="320x180")
    ap.add_argument("--seconds", type=float, default=15.0)
    ap.add_argument("--switches", default="qddgi;path:spp=1;ddgi:hysteresis=0.9")
    a = ap.parse_args()
    cmd = [sys.executable, "-m", "dyngi", "view", a.scene, "--techniques", "ddgi", "--res", a.res, "--port", "0"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, PYTHONUNBUFFERED="1"))
    try:
        line = proc.stdout.readline()
        m = re.search(r"http://([\d.]+:\d+)/", line)
        if not m:
            print("no address:", line, proc.stderr.read(), file=sys.stderr)
            return 1
        res = asyncio.run(client(f"ws://{m.group(1)}/ws", a.seconds, a.switches.split(";")))
    finally:
        proc.terminate()
        proc.wait(30)
    # the same technique without the viewer, right after: run_sequence's steady frame time at this load
    base = subprocess.run([sys.executable, "-c", (
        "import statistics, sys\n"
        "from dyngi.scene import load_scene\n"
        "from dyngi.techniques import create_technique\n"
        "from dyngi.experiments.runner import parse_res, run_sequence\n"
        f"sc = load_scene({a.scene!r}); t = create_technique('ddgi', sc)\n"
        f"seq = run_sequence(sc, t, 40, parse_res({a.res!r}), keep_images=False)\n"
        "print(statistics.median(seq.wall_ms[3:]))")], capture_output=True, text=True)
    try:
        res["plain_ms"] = float(base.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        res["plain_ms"] = float("nan")
    load = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    print(f"`{' '.join(['dyngi'] + cmd[3:])}`, {os.cpu_count()} cores, uptime: {load}\n")
    print(f"* streamed: **{res['fps']:.1f} frames/s** of ddgi over {a.seconds:g} s (error view off, playing); "
          f"ddgi median frame {res['ddgi_ms']:.1f} ms, tonemap + JPEG {res['encode_ms']:.1f} ms; the same ddgi "
          f"in run_sequence right after, without the viewer: {res['plain_ms']:.1f} ms/frame "
          f"({1e3 / res['plain_ms']:.1f} frames/s)")
    for s in res["switches"]:
        print(f"* switch to `{s['spec']}`: first frame on the page after **{s['latency_ms']:.0f} ms** = building "
              f"it {s['build_ms']:.0f} ms + its first frame {s['first_frame_ms']:.0f} ms (kernel compilation) + "
              f"the rest of the frame in flight and transfer; steady frames {s['steady_ms']:.0f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
