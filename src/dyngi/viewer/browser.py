"""Headless Chromium driven over the DevTools protocol, for the viewer's (and reports') browser tests.

Debian's ``chromium`` package is the browser (``run.sh`` installs it when missing; a browser that
downloads its own build cannot be fetched on these machines). It is started headless with
``--remote-debugging-port=0``; the port it picked is read from its ``DevToolsActivePort`` file, and
the page target is driven with the DevTools protocol over a websocket (the ``websockets`` package's
synchronous client): navigate, evaluate JavaScript, dispatch real mouse and key events, and capture
screenshots. No driver binary and no second browser library are needed.

    with Chromium() as br:
        page = br.new_page("http://127.0.0.1:8765/", width=800, height=600)
        page.wait_for("window.dyngiView && window.dyngiView.frames > 0")
        png = page.screenshot()
"""
from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import tempfile
import time
import urllib.request

CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    """Path of a Chromium binary: ``$DYNGI_CHROMIUM``, else the first of CANDIDATES on PATH."""
    env = os.environ.get("DYNGI_CHROMIUM")
    if env and os.path.exists(env):
        return env
    for c in CANDIDATES:
        p = shutil.which(c)
        if p:
            return p
    return None


class BrowserError(RuntimeError):
    pass


class Page:
    """One tab, driven over its DevTools websocket."""

    def __init__(self, ws_url: str, timeout: float = 30.0):
        from websockets.sync.client import connect

        self._conn = connect(ws_url, max_size=64 * 2 ** 20, open_timeout=timeout)
        self.ws = self._conn.__enter__()
        self._id = 0
        self.events: list = []

    def call(self, method: str, params: dict | None = None, timeout: float = 30.0) -> dict:
        self._id += 1
        mid = self._id
        self.ws.send(json.dumps({"id": mid, "method": method, "params": params or {}}))
        end = time.monotonic() + timeout
        while True:
            left = end - time.monotonic()
            if left <= 0:
                raise BrowserError(f"DevTools call {method} timed out after {timeout:g} s")
            msg = json.loads(self.ws.recv(timeout=left))
            if msg.get("id") == mid:
                if "error" in msg:
                    raise BrowserError(f"DevTools {method}: {msg['error'].get('message')}")
                return msg.get("result", {})
            self.events.append(msg)
            del self.events[:-200]

    def navigate(self, url: str, timeout: float = 30.0) -> None:
        self.call("Page.enable")
        self.call("Page.navigate", {"url": url}, timeout)
        self.wait_for("document.readyState === 'complete'", timeout)

    def evaluate(self, expr: str, timeout: float = 30.0):
        r = self.call("Runtime.evaluate", {"expression": expr, "returnByValue": True, "awaitPromise": True},
                      timeout)
        if "exceptionDetails" in r:
            d = r["exceptionDetails"]
            raise BrowserError(f"JavaScript error: {d.get('exception', {}).get('description') or d.get('text')}")
        return r.get("result", {}).get("value")

    def wait_for(self, expr: str, timeout: float = 30.0, interval: float = 0.1):
        """Poll the JavaScript expression ``expr`` until it is truthy; returns its value."""
        end = time.monotonic() + timeout
        last = None
        while time.monotonic() < end:
            last = self.evaluate(expr)
            if last:
                return last
            time.sleep(interval)
        raise BrowserError(f"timed out after {timeout:g} s waiting for: {expr} (last value {last!r})")

    def screenshot(self, clip: dict | None = None) -> bytes:
        """PNG bytes of the viewport (or of ``clip``: {x, y, width, height} in CSS pixels)."""
        params = {"format": "png"}
        if clip is not None:
            params["clip"] = dict(clip, scale=1)
        return base64.b64decode(self.call("Page.captureScreenshot", params)["data"])

    def mouse(self, kind: str, x: float, y: float, button: str = "left", buttons: int = 1, modifiers: int = 0):
        self.call("Input.dispatchMouseEvent", {"type": kind, "x": x, "y": y, "button": button,
                                               "buttons": buttons, "clickCount": 1, "modifiers": modifiers})

    def drag(self, x0: float, y0: float, x1: float, y1: float, steps: int = 10, button: str = "left"):
        """A real mouse drag (press, moves, release) from (x0, y0) to (x1, y1) in CSS pixels."""
        bmask = {"left": 1, "right": 2, "middle": 4}[button]
        self.mouse("mouseMoved", x0, y0, "none", 0)
        self.mouse("mousePressed", x0, y0, button, bmask)
        for i in range(1, steps + 1):
            a = i / steps
            self.mouse("mouseMoved", x0 + a * (x1 - x0), y0 + a * (y1 - y0), button, bmask)
            time.sleep(0.02)
        self.mouse("mouseReleased", x1, y1, button, 0)

    def key(self, code: str, key: str, hold_s: float = 0.0):
        """Press (and after ``hold_s`` release) a key: ``code`` like 'KeyW', ``key`` like 'w'."""
        self.call("Input.dispatchKeyEvent", {"type": "keyDown", "code": code, "key": key})
        if hold_s:
            time.sleep(hold_s)
        self.call("Input.dispatchKeyEvent", {"type": "keyUp", "code": code, "key": key})

    def close(self) -> None:
        try:
            self._conn.__exit__(None, None, None)
        except Exception:  # noqa: BLE001
            pass


class Chromium:
    """A headless Chromium process with a DevTools endpoint; a context manager that kills it on exit."""

    def __init__(self, binary: str | None = None, timeout: float = 30.0):
        self.binary = binary or find_chromium()
        if self.binary is None:
            raise BrowserError("no Chromium found: install Debian's 'chromium' package (run.sh does, as root)")
        self.timeout = timeout
        self.proc: subprocess.Popen | None = None
        self.profile: str | None = None
        self.port: int | None = None
        self.pages: list[Page] = []

    def __enter__(self) -> "Chromium":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def start(self) -> None:
        self.profile = tempfile.mkdtemp(prefix="dyngi-chromium-")
        args = [self.binary, "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--no-first-run", "--no-default-browser-check", "--disable-extensions",
                "--disable-background-networking", "--disable-component-update", "--disable-sync",
                "--mute-audio", "--hide-scrollbars", "--remote-debugging-address=127.0.0.1",
                "--remote-debugging-port=0", f"--user-data-dir={self.profile}", "about:blank"]
        self.proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL, start_new_session=True)
        port_file = os.path.join(self.profile, "DevToolsActivePort")
        end = time.monotonic() + self.timeout
        while time.monotonic() < end:
            if self.proc.poll() is not None:
                raise BrowserError(f"Chromium exited at start (status {self.proc.returncode})")
            try:
                with open(port_file) as f:
                    first = f.readline().strip()
                if first:
                    self.port = int(first)
                    break
            except (OSError, ValueError):
                pass
            time.sleep(0.05)
        if self.port is None:
            self.close()
            raise BrowserError(f"Chromium did not open its DevTools port within {self.timeout:g} s")

    def _http(self, path: str, method: str = "GET"):
        req = urllib.request.Request(f"http://127.0.0.1:{self.port}{path}", method=method)
        with urllib.request.urlopen(req, timeout=self.timeout) as r:
            return json.loads(r.read().decode())

    def new_page(self, url: str | None = None, width: int = 1000, height: int = 700) -> Page:
        target = self._http("/json/new?about:blank", method="PUT")
        page = Page(target["webSocketDebuggerUrl"], self.timeout)
        self.pages.append(page)
        page.call("Emulation.setDeviceMetricsOverride", {"width": width, "height": height,
                                                         "deviceScaleFactor": 1, "mobile": False})
        if url is not None:
            page.navigate(url, self.timeout)
        return page

    def close(self) -> None:
        for p in self.pages:
            p.close()
        self.pages.clear()
        if self.proc is not None:
            try:
                os.killpg(self.proc.pid, 15)
            except OSError:
                pass
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                try:
                    os.killpg(self.proc.pid, 9)
                except OSError:
                    pass
                self.proc.wait(timeout=10)
            self.proc = None
        if self.profile is not None:
            shutil.rmtree(self.profile, ignore_errors=True)
            self.profile = None
