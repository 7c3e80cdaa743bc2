"""The viewer's web server: one page, one websocket, frames pushed as JPEG.

Why ``websockets`` (and not viser, aiohttp or FastAPI + uvicorn): the viewer needs exactly one HTML
page, one script and one bidirectional channel. The ``websockets`` package (pure Python, no
dependencies of its own) serves all three from one asyncio server (plain HTTP GETs are answered in its
``process_request`` hook), and the same package is the client the browser tests use to drive Chromium
over the DevTools protocol, so one small dependency covers the server and its tests. aiohttp would
bring six compiled dependencies, FastAPI + uvicorn a web framework and an ASGI server for three routes,
and viser a scene-graph client built for its own Three.js renderer, while our frames are ray-traced
images made on the server.

Protocol (``/ws``): the server sends JSON text messages (``state``, ``stats``, ``busy``,
``errorview``, ``error``) and binary frames: a 4-byte little-endian header length, a JSON header
(``slot`` 'a' | 'b' | 'err-a' | 'err-b', ``spec``, ``frame``, ``t``, ``w``, ``h``) and the JPEG. Each
client has its own sender that always sends the newest frame of each slot and drops older ones, so a
slow client never holds back the renderer. The page sends JSON commands: ``technique`` {slot, spec},
``play`` {playing}, ``seek`` {t}, ``camera`` {op, ...} (see :mod:`dyngi.viewer.camera`), ``overlay``
{name}, ``error_view`` {on}, ``exposure`` {value}. A bad command is answered with an ``error`` message
to that page; the server carries on.
"""
from __future__ import annotations

import asyncio
import json
import os
import signal
import struct
import sys
import threading
import time
from importlib import resources

from ..errors import DyngiError

DEFAULT_PORT = 8765
STATIC = {"/": ("index.html", "text/html; charset=utf-8"),
          "/index.html": ("index.html", "text/html; charset=utf-8"),
          "/viewer.js": ("viewer.js", "text/javascript; charset=utf-8")}


def _static(name: str) -> bytes:
    return resources.files("dyngi.viewer").joinpath("static", name).read_bytes()


class _Client:
    def __init__(self, ws):
        self.ws = ws
        self.json: dict = {}           # key -> message; newer replaces older of the same key
        self.frames: dict = {}         # slot -> bytes; newest only
        self.event = asyncio.Event()
        self.sent_frames = 0


class ViewerServer:
    """The asyncio server around a :class:`~dyngi.viewer.session.RenderSession`."""

    def __init__(self, session, host: str = "127.0.0.1", port: int | None = None):
        self.session = session
        self.host = host
        self.port = port
        self.clients: set[_Client] = set()
        self.loop: asyncio.AbstractEventLoop | None = None
        self.stop_event: asyncio.Event | None = None
        self.bound_port: int | None = None
        self.started = threading.Event()
        self._error_seq = 0

    # -- from the render thread ----------------------------------------------------------------
    def publish(self, kind: str, payload) -> None:
        loop = self.loop
        if loop is None or loop.is_closed():
            return
        try:
            loop.call_soon_threadsafe(self._dispatch, kind, payload)
        except RuntimeError:       # loop closed while shutting down
            pass

    def _dispatch(self, kind: str, payload) -> None:
        if kind == "frame":
            header, jpeg = payload
            h = json.dumps(header).encode()
            data = struct.pack("<I", len(h)) + h + jpeg
            for c in self.clients:
                c.frames[header["slot"]] = data
                c.event.set()
            return
        if kind == "stats":
            self._broadcast(("stats", payload["slot"]), payload)
        elif kind == "state":
            self._broadcast(("state",), payload)
        elif kind == "errorview":
            self._broadcast(("errorview",), payload)
        elif kind == "error":
            self._error_seq += 1
            self._broadcast(("error", self._error_seq), {"type": "error", "message": payload["message"]})
            print(f"dyngi view: error: {payload['message']}", file=sys.stderr, flush=True)

    def _broadcast(self, key, msg) -> None:
        for c in self.clients:
            self._queue(c, key, msg)

    @staticmethod
    def _queue(c: _Client, key, msg) -> None:
        c.json[key] = msg
        c.event.set()

    # -- HTTP ----------------------------------------------------------------------------------
    def _process_request(self, connection, request):
        from websockets.datastructures import Headers
        from websockets.http11 import Response

        path = request.path.split("?", 1)[0]
        if path == "/ws":
            return None
        if path in STATIC:
            name, ctype = STATIC[path]
            body = _static(name)
            headers = Headers([("Content-Type", ctype), ("Content-Length", str(len(body))),
                               ("Cache-Control", "no-store"), ("Connection", "close")])
            return Response(200, "OK", headers, body)
        if path == "/healthz":
            return connection.respond(200, "ok\n")
        return connection.respond(404, f"not found: {path}\n")

    # -- websocket -----------------------------------------------------------------------------
    async def _handler(self, ws) -> None:
        c = _Client(ws)
        self.clients.add(c)
        self._queue(c, ("state",), self.session.state())
        sender = asyncio.create_task(self._sender(c))
        try:
            async for raw in ws:
                await self._command(c, raw)
        except Exception:  # noqa: BLE001  (a client that went away)
            pass
        finally:
            self.clients.discard(c)
            sender.cancel()

    async def _sender(self, c: _Client) -> None:
        try:
            while True:
                await c.event.wait()
                c.event.clear()
                msgs, c.json = list(c.json.values()), {}
                frames, c.frames = list(c.frames.values()), {}
                for m in msgs:
                    await c.ws.send(json.dumps(m))
                for f in frames:
                    await c.ws.send(f)
                    c.sent_frames += 1
        except asyncio.CancelledError:
            raise
        except Exception:  # noqa: BLE001  (connection closed)
            return

    async def _command(self, c: _Client, raw) -> None:
        s = self.session
        try:
            if isinstance(raw, bytes):
                raise DyngiError("binary messages are not understood")
            try:
                msg = json.loads(raw)
            except ValueError:
                raise DyngiError("a message was not JSON") from None
            if not isinstance(msg, dict):
                raise DyngiError("a message was not a JSON object")
            kind = msg.get("type")
            if kind == "technique":
                s.set_technique(str(msg.get("slot", "a")), msg.get("spec"))
            elif kind == "play":
                s.set_playing(bool(msg.get("playing")))
            elif kind == "seek":
                s.seek(_number(msg, "t"))
            elif kind == "camera":
                follow = s.follow
                s.camera(msg)
                if s.follow == follow and msg.get("op") != "reset":
                    return                  # camera moves: no state broadcast per mouse move
            elif kind == "overlay":
                s.set_overlay(str(msg.get("name")))
            elif kind == "error_view":
                s.set_error_view(bool(msg.get("on")))
            elif kind == "exposure":
                s.set_exposure(_number(msg, "value"))
            elif kind == "ping":
                self._queue(c, ("pong",), {"type": "pong", "id": msg.get("id")})
                return
            else:
                raise DyngiError(f"unknown message type '{kind}'; valid: technique, play, seek, camera, overlay, "
                                 "error_view, exposure, ping")
        except DyngiError as e:
            self._queue(c, ("error", "cmd", time.perf_counter()), {"type": "error", "message": str(e)})
            return
        self._broadcast(("state",), s.state())

    async def _busy_ticker(self) -> None:
        """Every 0.25 s: a frame in flight for more than 0.4 s is reported with its elapsed time."""
        shown = False
        while True:
            await asyncio.sleep(0.25)
            b = self.session.busy
            if b is not None and time.perf_counter() - b["since"] > 0.4:
                self._broadcast(("busy",), {"type": "busy", "busy": True, "spec": b["spec"], "slot": b["slot"],
                                            "what": b["what"], "frame": b["frame"],
                                            "elapsed_ms": 1e3 * (time.perf_counter() - b["since"]),
                                            "expected_ms": b["expected_ms"]})
                shown = True
            elif shown and b is None:
                self._broadcast(("busy",), {"type": "busy", "busy": False})
                shown = False

    # -- lifecycle -----------------------------------------------------------------------------
    async def _bind(self):
        from websockets.asyncio.server import serve

        ports = [self.port] if self.port is not None else [DEFAULT_PORT, 0]
        last = None
        for p in ports:
            try:
                return await serve(self._handler, self.host, p, process_request=self._process_request,
                                   max_size=2 ** 20, compression=None, ping_interval=20, ping_timeout=60)
            except OSError as e:
                last = e
        what = f"port {self.port}" if self.port is not None else f"port {DEFAULT_PORT} or a free port"
        raise DyngiError(f"cannot listen on {self.host} {what}: {last.strerror or last}"
                         + ("; choose another with --port N (0: any free port)" if self.port else ""))

    async def run(self, on_ready=None) -> None:
        """Serve until :meth:`stop` (or SIGINT/SIGTERM when run from the main thread)."""
        self.loop = asyncio.get_running_loop()
        self.stop_event = asyncio.Event()
        server = await self._bind()
        self.bound_port = server.sockets[0].getsockname()[1]
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                try:
                    self.loop.add_signal_handler(sig, self.stop_event.set)
                except (NotImplementedError, RuntimeError):
                    pass
        ticker = asyncio.create_task(self._busy_ticker())
        self.started.set()
        if on_ready is not None:
            on_ready(self)
        try:
            await self.stop_event.wait()
        finally:
            ticker.cancel()
            server.close()
            try:
                await asyncio.wait_for(server.wait_closed(), 5.0)
            except asyncio.TimeoutError:
                pass
            self.loop = None

    def stop(self) -> None:
        """Ask :meth:`run` to end (from any thread)."""
        loop, ev = self.loop, self.stop_event
        if loop is not None and ev is not None:
            try:
                loop.call_soon_threadsafe(ev.set)
            except RuntimeError:
                pass

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.bound_port}/"


def _number(msg: dict, key: str) -> float:
    try:
        return float(msg[key])
    except (KeyError, TypeError, ValueError):
        raise DyngiError(f"'{msg.get('type')}' needs a number '{key}'") from None


def run_viewer(scene_name: str, techniques: str = "ddgi", host: str = "127.0.0.1", port: int | None = None,
               res=(320, 180), device: str = "cpu", ref_spp: int = 128, still_frames: int = 32,
               out=sys.stdout) -> int:
    """``dyngi view``: load the scene, build the first technique, serve until Ctrl-C / SIGTERM.

    Input errors (unknown scene or technique, bad spec, busy port) raise :class:`DyngiError` before
    anything is served."""
    from .. import backend
    from ..scene import load_scene
    from ..techniques.base import split_spec_list
    from .session import RenderSession

    backend.set_device(device)
    specs = split_spec_list(techniques)
    if not specs:
        raise DyngiError("--techniques is empty; name at least one spec, e.g. ddgi or ddgi:hysteresis=0.9")
    scene = load_scene(scene_name)
    holder = {}
    session = RenderSession(scene, specs, res, publish=lambda k, p: holder["server"].publish(k, p),
                            device=device, ref_spp=ref_spp, still_frames=still_frames)
    server = ViewerServer(session, host, port)
    holder["server"] = server
    main_thread = threading.current_thread() is threading.main_thread()
    if main_thread:          # SIGTERM before the server runs (building the techniques) stops as Ctrl-C does
        old_term = signal.signal(signal.SIGTERM, _raise_interrupt)
    session.start()
    try:
        while not session.ready.wait(0.2):
            pass
    except KeyboardInterrupt:
        _stop_or_exit(session, out)
        raise
    if session.startup_error:
        session.stop(5.0)
        raise DyngiError(session.startup_error)

    def ready(srv):
        local = host in ("127.0.0.1", "localhost", "::1")
        print(f"dyngi view: '{scene.name}' with {', '.join(specs)} at {srv.url}  (Ctrl-C stops)", file=out,
              flush=True)
        if not local:
            print(f"dyngi view: warning: listening on {host}, not only this machine: anyone who can reach it "
                  "can drive the renderer (no authentication)", file=sys.stderr, flush=True)

    try:
        asyncio.run(server.run(on_ready=ready))
    except KeyboardInterrupt:
        pass
    finally:
        _stop_or_exit(session, out)
        if main_thread:
            signal.signal(signal.SIGTERM, old_term)
    print("dyngi view: stopped", file=out, flush=True)
    return 0


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


def _stop_or_exit(session, out, timeout: float = 10.0) -> None:
    """Stop the render thread; if a frame is still rendering after ``timeout`` s, end the process now
    (a daemon thread inside a Dr.Jit kernel at interpreter shutdown could crash it)."""
    if not session.stop(timeout):
        print(f"dyngi view: stopped (a frame was still rendering after {timeout:g} s; not waiting for it)",
              file=out, flush=True)
        sys.stderr.flush()
        os._exit(0)
