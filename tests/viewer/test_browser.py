"""`dyngi view` in a real browser: Debian's Chromium, headless, driven over the DevTools protocol.

One viewer process (the real command line, 96x54, cheap settings) serves the whole module; the tests
run in order and the last one stops it with SIGTERM. Chromium comes from run.sh's set-up; without it
the tests skip, except under CI (CI=true), where a missing browser is a failure: these tests must run.
"""
import io
import os
import re
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from dyngi.viewer.browser import Chromium, find_chromium

pytestmark = pytest.mark.timeout(300)   # a slow CI machine, another test worker compiling beside it

SCENE = "cornell-moving-light"
SPEC_A = "ddgi:rays_per_probe=64:probe_counts=4"
SPEC_SWITCH = "path:spp=1"
SPEC_SPLIT = "path:spp=1:max_depth=2"


def _need_chromium():
    if find_chromium() is None:
        msg = "Debian's chromium is not installed (bash run.sh installs it as root: apt-get install chromium)"
        if os.environ.get("CI"):
            pytest.fail("CI must run the browser tests: " + msg)
        pytest.skip(msg)


def _children(pid: int) -> list[int]:
    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat") as f:
                    ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
            if ppid == pid:
                out.append(int(d))
    return out


@pytest.fixture(scope="module")
def viewer(tmp_path_factory):
    _need_chromium()
    cache = tmp_path_factory.mktemp("cache")
    env = dict(os.environ, DYNGI_CACHE=str(cache), PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "dyngi", "view", SCENE, "--techniques",
                             SPEC_A, "--res", "96x54", "--port", "0", "--ref-spp", "4"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    line = proc.stdout.readline()
    m = re.search(r"(http://127\.0\.0\.1:(\d+)/(?:\?token=[\w-]+)?)", line)
    if not m:
        proc.kill()
        pytest.fail(f"dyngi view printed no address: {line!r} {proc.stderr.read()[-2000:]}")
    info = {"proc": proc, "url": m.group(1), "port": int(m.group(2))}
    yield info
    if proc.poll() is None:
        proc.kill()
        proc.wait(10)


@pytest.fixture(scope="module")
def page(viewer):
    with Chromium() as br:
        p = br.new_page(viewer["url"], width=900, height=700)
        p.wait_for("window.dyngiView && window.dyngiView.frames >= 2", 120)
        yield p


def _canvas_png(page) -> np.ndarray:
    from PIL import Image

    r = page.evaluate("(() => { const r = document.getElementById('view').getBoundingClientRect();"
                      " return {x: r.x, y: r.y, width: r.width, height: r.height}; })()")
    png = page.screenshot(clip=r)
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.float32)


def _blocks(img: np.ndarray, n: int = 6) -> np.ndarray:
    """Block means (n x n): compares the view's layout, not its per-pixel noise."""
    h, w = img.shape[:2]
    return np.array([[img[i * h // n:(i + 1) * h // n, j * w // n:(j + 1) * w // n].mean()
                      for j in range(n)] for i in range(n)])


def _frames(page, slot="a") -> int:
    return page.evaluate(f"window.dyngiView.framesBySlot['{slot}'] || 0")


def _wait_frames(page, n: int, slot="a", timeout=90):
    start = _frames(page, slot)
    page.wait_for(f"(window.dyngiView.framesBySlot['{slot}'] || 0) >= {start + n}", timeout)


def _wait_idle(page, quiet_s=0.8, timeout=90):
    """Wait until no frame has arrived for ``quiet_s``: paused and still, the viewer stops after its still
    frames, so the image on the page no longer changes."""
    end = time.monotonic() + timeout
    last, since = _frames(page), time.monotonic()
    while time.monotonic() < end:
        time.sleep(0.1)
        n = _frames(page)
        if n != last:
            last, since = n, time.monotonic()
        elif time.monotonic() - since >= quiet_s:
            return
    raise AssertionError(f"the viewer kept rendering for {timeout} s while paused and still")


def test_binds_to_localhost_only(viewer):
    assert viewer["url"].startswith("http://127.0.0.1:")


def test_page_loads_and_shows_a_frame(page):
    img = _canvas_png(page)
    assert img.shape[0] > 50 and img.shape[1] > 90
    assert img.std() > 10 and img.mean() > 10, "blank view"
    st = page.evaluate("window.dyngiView.stats.a")
    assert st["spec"] == SPEC_A and st["stats"]["ms"] and st["stats"]["rays"]
    # the stats panel shows per-stage milliseconds and rays
    assert page.evaluate("document.querySelectorAll('#stats tr.stage').length") >= 2


def test_camera_drag_changes_the_image(page):
    page.evaluate("window.dyngiView.send({type: 'play', playing: false})")
    page.wait_for("window.dyngiView.state && window.dyngiView.state.playing === false", 60)
    _wait_idle(page)
    b = _canvas_png(page)
    r = page.evaluate("(() => { const r = document.getElementById('view').getBoundingClientRect();"
                      " return {x: r.x, y: r.y, w: r.width, h: r.height}; })()")
    cx, cy = r["x"] + r["w"] / 2, r["y"] + r["h"] / 2
    page.drag(cx, cy, cx + 0.4 * r["w"], cy + 0.1 * r["h"], steps=8)
    _wait_frames(page, 4)
    c = _canvas_png(page)
    moved = np.abs(_blocks(c) - _blocks(b)).mean()
    assert moved > 3.0, moved
    assert page.evaluate("window.dyngiView.state.follow") is False


def test_fly_keys_move_the_camera(page):
    page.key("KeyR", "r")                       # the orbit above left the box; back inside
    page.wait_for("window.dyngiView.state.follow === true", 60)
    _wait_idle(page)
    before = _canvas_png(page)
    page.key("KeyW", "w", hold_s=0.5)           # fly forward for half a second
    _wait_frames(page, 2)
    _wait_idle(page)
    after = _canvas_png(page)
    moved = np.abs(_blocks(after) - _blocks(before)).mean()
    assert moved > 3.0, moved


def test_technique_switch_changes_the_stats(page):
    before = set(page.evaluate("Object.keys(window.dyngiView.stats.a.stats.ms)"))
    page.evaluate(f"document.getElementById('specA').value = '{SPEC_SWITCH}';"
                  "document.getElementById('applyA').click()")
    page.wait_for(f"window.dyngiView.stats.a && window.dyngiView.stats.a.spec === '{SPEC_SWITCH}'", 90)
    after = set(page.evaluate("Object.keys(window.dyngiView.stats.a.stats.ms)"))
    assert after and after != before
    assert page.evaluate("document.querySelector('#stats th').textContent").endswith(SPEC_SWITCH)
    sw = page.evaluate("window.dyngiView.stats.a.switch_ms")
    assert sw is None or sw > 0


def test_bad_spec_is_an_error_on_the_page_not_a_dead_server(page, viewer):
    page.evaluate("document.getElementById('specA').value = 'ddgi:bogus=1';"
                  "document.getElementById('applyA').click()")
    page.wait_for("window.dyngiView.errors.some(e => e.includes(\"unknown parameter 'bogus'\"))", 60)
    assert "bogus" in page.evaluate("document.getElementById('errors').textContent")
    page.evaluate("window.dyngiView.send({type: 'technique', slot: 'a', spec: 'no-such-technique'})")
    page.wait_for("window.dyngiView.errors.some(e => e.includes(\"unknown technique 'no-such-technique'\"))", 60)
    page.evaluate("window.dyngiView.send({type: 'camera', op: 'orbit', dx: 5, dy: 0})")   # still serving
    _wait_frames(page, 2)
    assert viewer["proc"].poll() is None
    assert page.evaluate("window.dyngiView.stats.a.spec") == SPEC_SWITCH    # the old technique stays


def test_split_view_renders_both(page):
    page.evaluate(f"document.getElementById('specB').value = '{SPEC_SPLIT}';"
                  "document.getElementById('applyB').click()")
    page.wait_for(f"window.dyngiView.stats.b && window.dyngiView.stats.b.spec === '{SPEC_SPLIT}'", 90)
    _wait_frames(page, 1, "b")
    assert page.evaluate("document.getElementById('labelB').style.display") == "block"
    page.evaluate("document.getElementById('offB').click()")
    page.wait_for("window.dyngiView.state.want_b === null", 60)


def test_probe_overlay_and_error_view(page):
    page.key("KeyR", "r")                     # back to the scene's camera, inside the box
    page.wait_for("window.dyngiView.state.follow === true", 60)
    page.evaluate(f"window.dyngiView.send({{type: 'technique', slot: 'a', spec: '{SPEC_A}'}})")
    page.wait_for(f"window.dyngiView.state.overlays.includes('probes') && "
                  f"window.dyngiView.stats.a.spec === '{SPEC_A}'", 30)
    _wait_idle(page)
    base = _canvas_png(page)
    page.evaluate("const s = document.getElementById('overlay'); s.value = 'probes';"
                  "s.dispatchEvent(new Event('change'))")
    page.wait_for("window.dyngiView.stats.a.overlay_ms > 0", 90)
    _wait_frames(page, 1)
    drawn = np.abs(_blocks(_canvas_png(page), 12) - _blocks(base, 12)).mean()
    assert drawn > 1.5, drawn
    # error view: a 4-spp reference at the current (still) view, HDR-FLIP in [0, 1]
    page.evaluate("const e = document.getElementById('errview'); e.checked = true;"
                  "e.dispatchEvent(new Event('change'))")
    ev = page.wait_for("window.dyngiView.errorview && window.dyngiView.errorview.state === 'ready' &&"
                       " window.dyngiView.errorview", 60)
    assert 0.0 < ev["flip"]["a"] < 1.0
    page.wait_for("window.dyngiView.framesBySlot['err-a'] > 0", 60)


def test_sigterm_shuts_down_cleanly(viewer, page):
    proc = viewer["proc"]
    kids = _children(proc.pid)       # the error view's reference process, when the test above started it
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err[-2000:]
    assert "stopped" in out and "Traceback" not in err
    for k in kids:                            # the reference process is gone too
        assert not os.path.exists(f"/proc/{k}") or open(f"/proc/{k}/stat").read().split()[2] == "Z"
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)   # as any server binds (TIME_WAIT is no listener)
    s.bind(("127.0.0.1", viewer["port"]))     # nobody listens there any more: the port is free
    s.listen(1)
    s.close()
    page.wait_for("window.dyngiView.connected === false", 60)
