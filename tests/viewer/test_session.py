"""The viewer's render loop without a browser: errors are reported and the loop carries on."""
import threading
import time

import pytest

from dyngi.errors import DyngiError
from dyngi.scene import load_scene
from dyngi.viewer.session import RenderSession


class Sink:
    def __init__(self):
        self.msgs = []
        self.cv = threading.Condition()

    def __call__(self, kind, payload):
        with self.cv:
            self.msgs.append((kind, payload))
            self.cv.notify_all()

    def wait(self, pred, timeout=60):
        end = time.monotonic() + timeout
        with self.cv:
            while not any(pred(k, p) for k, p in self.msgs):
                left = end - time.monotonic()
                if left <= 0:
                    raise AssertionError("timed out; got: " + repr([(k, p if k != "frame" else p[0])
                                                                   for k, p in self.msgs[-10:]]))
                self.cv.wait(left)
            return [p for k, p in self.msgs if pred(k, p)]


@pytest.fixture
def session(backend):
    sink = Sink()
    s = RenderSession(load_scene("cornell-static"), ["path:spp=1"], (16, 9), sink, still_frames=4)
    s.start()
    assert s.ready.wait(60) and s.startup_error is None
    yield s, sink
    assert s.stop(60)
    assert not s.thread.is_alive()


def test_frames_and_stats_flow(session):
    s, sink = session
    st = sink.wait(lambda k, p: k == "stats" and p["frame"] >= 1)[-1]
    assert st["spec"] == "path:spp=1" and st["stats"]["ms"] and st["stats"]["rays"]
    hdr, jpeg = sink.wait(lambda k, p: k == "frame")[0]
    assert hdr["w"] == 16 and hdr["h"] == 9 and jpeg[:2] == b"\xff\xd8"


def test_bad_spec_is_refused_before_the_worker(session):
    s, _ = session
    with pytest.raises(DyngiError, match="unknown parameter 'nope'"):
        s.set_technique("a", "path:nope=1")
    with pytest.raises(DyngiError, match="unknown view slot"):
        s.set_technique("c", "path")
    with pytest.raises(DyngiError, match="unknown overlay"):
        s.set_overlay("sparkles")


def test_a_failing_frame_is_an_error_and_the_loop_lives_on(session):
    s, sink = session
    sink.wait(lambda k, p: k == "stats")
    tech = s.slots["a"].tech

    def boom(frame):
        raise RuntimeError("kernel exploded\nsecond line")
    tech.step = boom
    s.seek(0.5)                          # a change: the loop renders again
    err = sink.wait(lambda k, p: k == "error")[0]["message"]
    assert "failed on frame" in err and "RuntimeError: kernel exploded" in err and "second line" not in err
    assert s.thread.is_alive()
    s.set_technique("a", "path:spp=2")   # a new technique renders again
    sink.wait(lambda k, p: k == "stats" and p["spec"] == "path:spp=2")


def test_paused_and_still_goes_idle(session):
    s, sink = session
    s.set_playing(False)
    sink.wait(lambda k, p: k == "stats")
    end = time.monotonic() + 120          # a cold kernel cache on a slow machine: the still frames take a while
    while not (s.still >= s.still_frames and s.busy is None) and time.monotonic() < end:
        time.sleep(0.05)
    assert s.still >= s.still_frames, "the loop never went idle"
    time.sleep(0.2)
    n = sum(k == "frame" for k, _ in sink.msgs)
    time.sleep(1.0)
    assert sum(k == "frame" for k, _ in sink.msgs) == n        # nothing changes: nothing rendered
    s.camera({"op": "orbit", "dx": 10, "dy": 0})
    sink.wait(lambda k, p: k == "frame" and sum(kk == "frame" for kk, _ in sink.msgs) > n)
