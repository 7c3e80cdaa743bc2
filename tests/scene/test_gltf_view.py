"""``dyngi view`` plays a user's animated glTF scene: the viewer's render loop (no browser) on the example
box (examples/animated_box.py) renders frames at the times it is sent to, with ddgi, and carries on."""
from __future__ import annotations

import os
import runpy

import numpy as np

from dyngi.scene import load_scene
from dyngi.viewer.session import RenderSession
from viewer.test_session import Sink

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_viewer_plays_the_gltf_box(backend, tmp_path):
    box = runpy.run_path(os.path.join(ROOT, "examples", "animated_box.py"))["write"](str(tmp_path / "box.gltf"))
    sc = load_scene(box, fps=24)
    s = RenderSession(sc, ["ddgi"], (16, 12), Sink(), still_frames=2)
    sink = s.publish
    s.start()
    try:
        assert s.ready.wait(120) and s.startup_error is None, s.startup_error
        st = sink.wait(lambda k, p: k == "state")[0]
        assert st["duration"] == 3.0 and st["fps"] == 24.0 and st["playing"]      # an animated file plays
        sink.wait(lambda k, p: k == "stats" and p["frame"] >= 2)
        ts = [p["t"] for k, p in sink.msgs if k == "stats"]
        assert len(ts) >= 3 and all(b > a for a, b in zip(ts, ts[1:])), ts          # time advances
        s.set_playing(False)
        for t in (0.5, 2.5):
            s.seek(t)
            sink.wait(lambda k, p, t=t: k == "stats" and abs(p["t"] - t) < 1e-9)
        assert not [p for k, p in sink.msgs if k == "error"]
        assert sc.time == 2.5
        lid = np.asarray(sc.params["lid.vertex_positions"]).reshape(-1, 3)
        assert lid[:, 1].max() > 0.9          # open at 2.5 s: the lid stands up above the box (height 0.8)
    finally:
        assert s.stop(60)
