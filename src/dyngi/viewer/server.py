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
to that page; the server carries on. A message over 1 MiB closes that connection with code 1009
(message too big); the server and its other pages carry on.

Who may drive it: the viewer renders on this machine and shows what it renders, so it answers only its
user, as Jupyter does (the anchor here):

* a random **token** (``secrets.token_urlsafe``, 192 bits) is printed in the page's address
  (``http://127.0.0.1:8765/?token=...``); the page and the websocket need it (``?token=`` in the URL, or
  the ``dyngi-view-token`` cookie the page sets: ``HttpOnly``, ``SameSite=Strict``). Always when ``--host``
  is not a loopback address; on loopback by default too (``--no-token`` turns it off there only);
* the websocket handshake is refused (403) unless its ``Origin`` is the page's own: ``http://`` + the
  ``Host`` the request was sent to. A browser always sends ``Origin`` on a websocket, so another site's
  page (cross-site WebSocket hijacking) is refused even with ``--no-token``; a client with no ``Origin``
  (a script, not a browser) must bring the token;
* on a loopback server the ``Host`` must name a loopback address (``127.0.0.1``, ``localhost``, ``[::1]``):
  a page whose own name resolves to 127.0.0.1 (DNS rebinding) passes the origin check but not this one.
"""
from __future__ import annotations

import asyncio
import hmac
import json
import os
import secrets
import signal
import struct
import sys
import threading
import time
from http.cookies import SimpleCookie
from importlib import resources
from urllib.parse import parse_qs, urlsplit

from .. import backend
from ..errors import DyngiError
from ..scene import load_scene
from ..techniques.base import split_spec_list
from .session import RenderSession

DEFAULT_PORT = 8765
TOKEN_COOKIE = "dyngi-view-token"
LOOPBACK = ("127.0.0.1", "localhost", "::1")
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

    def __init__(self, session, host: str = "127.0.0.1", port: int | None = None, token: bool = True):
        """``token``: require a random token (see the module docstring); only a loopback ``host`` may turn
        it off."""
        check_token_host(host, token)
        self.session = session
        self.host = host
        self.port = port
        self.token = secrets.token_urlsafe(24) if token else None
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
        refused = self._refusal(request, path)
        if refused:
            return connection.respond(403, f"forbidden: {refused}\n")
        if path == "/ws":
            return None
        if path in STATIC:
            name, ctype = STATIC[path]
            body = _static(name)
            headers = Headers([("Content-Type", ctype), ("Content-Length", str(len(body))),
                               ("Cache-Control", "no-store"), ("Connection", "close")])
            if self.token is not None and name == "index.html":
                headers["Set-Cookie"] = f"{TOKEN_COOKIE}={self.token}; HttpOnly; SameSite=Strict; Path=/"
            return Response(200, "OK", headers, body)
        if path == "/healthz":
            return connection.respond(200, "ok\n")
        return connection.respond(404, f"not found: {path}\n")

    def _refusal(self, request, path: str) -> str | None:
        """Why this request may not be answered (None: it may). The page and the websocket need the token;
        the websocket also needs the page's own origin; a loopback server needs a loopback ``Host``."""
        if path not in ("/", "/index.html", "/ws"):
            return None                      # the script, the health check and 404s carry nothing private
        hosts, origins = request.headers.get_all("Host"), request.headers.get_all("Origin")
        if len(hosts) != 1 or len(origins) > 1:
            return "one Host header and at most one Origin header expected"
        host = hosts[0]
        if is_loopback(self.host) and not is_loopback(_host_name(host)):
            return f"Host '{host}' is not this machine's loopback address"
        origin = origins[0] if origins else None
        if path == "/ws" and origin is not None and origin != f"http://{host}":
            return f"websocket from another origin ('{origin}'); only this viewer's own page may connect"
        if self.token is None:
            return None
        given = parse_qs(urlsplit(request.path).query).get("token", [""])[0]
        if not given:
            cookie = SimpleCookie()
            try:
                cookie.load("; ".join(request.headers.get_all("Cookie")))
            except Exception:  # noqa: BLE001  (a malformed cookie header: no token)
                pass
            given = cookie[TOKEN_COOKIE].value if TOKEN_COOKIE in cookie else ""
        if not hmac.compare_digest(given.encode(), self.token.encode()):
            return "a wrong or missing token; open the address 'dyngi view' printed (it ends in ?token=...)"
        return None

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
        """The page's address, with the token when one is required."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.bound_port}/" + (f"?token={self.token}" if self.token else "")


def is_loopback(host: str) -> bool:
    """True for a name or address of this machine only (127.0.0.0/8, ::1, localhost)."""
    h = host.strip("[]").lower()
    return h in LOOPBACK or h.startswith("127.")


def check_token_host(host: str, token: bool) -> None:
    """Serving without a token is allowed only on a loopback address."""
    if not token and not is_loopback(host):
        raise DyngiError(f"--no-token is allowed only on a loopback address ({', '.join(LOOPBACK)}); "
                         f"--host {host} is reachable from other machines")


def _host_name(host_header: str) -> str:
    """The host of a ``Host`` header (``name:port``, ``[v6]:port`` or a bare name)."""
    h = host_header.strip()
    if h.startswith("["):
        return h[1:h.find("]")] if "]" in h else h
    return h.rsplit(":", 1)[0] if h.count(":") == 1 else h


def _number(msg: dict, key: str) -> float:
    try:
        return float(msg[key])
    except (KeyError, TypeError, ValueError):
        raise DyngiError(f"'{msg.get('type')}' needs a number '{key}'") from None


def run_viewer(scene_name: str, techniques: str = "ddgi", host: str = "127.0.0.1", port: int | None = None,
               res=(320, 180), device: str = "cpu", ref_spp: int = 128, still_frames: int = 32,
               out=sys.stdout, token: bool = True) -> int:
    """``dyngi view``: load the scene, build the first technique, serve until Ctrl-C / SIGTERM.

    Input errors (unknown scene or technique, bad spec, busy port) raise :class:`DyngiError` before
    anything is served."""
    check_token_host(host, token)
    backend.set_device(device)
    specs = split_spec_list(techniques)
    if not specs:
        raise DyngiError("--techniques is empty; name at least one spec, e.g. ddgi or ddgi:hysteresis=0.9")
    scene = load_scene(scene_name)
    holder = {}
    session = RenderSession(scene, specs, res, publish=lambda k, p: holder["server"].publish(k, p),
                            device=device, ref_spp=ref_spp, still_frames=still_frames)
    server = ViewerServer(session, host, port, token=token)
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
        print(f"dyngi view: '{scene.name}' with {', '.join(specs)} at {srv.url}  (Ctrl-C stops)", file=out,
              flush=True)
        if not is_loopback(host):
            print(f"dyngi view: note: listening on {host}, not only this machine: the address above carries "
                  "the token that lets its holder drive the renderer; share it only with whom you trust",
                  file=sys.stderr, flush=True)

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
