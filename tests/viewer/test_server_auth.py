"""The viewer answers only its user: the websocket refuses other sites' pages (cross-site WebSocket
hijacking) and, with the token on (the default), any client without the token printed in the page's
address; bad or oversized messages get an error and the server carries on. A stub session stands in for
the renderer (these tests check the server, not the frames)."""
from __future__ import annotations

import asyncio
import json
import threading
import urllib.error
import urllib.request

import pytest

websockets = pytest.importorskip("websockets")
from websockets.asyncio.client import connect  # noqa: E402

from dyngi.errors import DyngiError  # noqa: E402
from dyngi.viewer.server import ViewerServer, is_loopback  # noqa: E402


class _StubSession:
    """What the server asks of a RenderSession: its state, its busy flag, and the commands."""
    busy = None
    follow = False

    def __init__(self):
        self.techniques = []

    def state(self):
        return {"type": "state", "techniques": list(self.techniques)}

    def set_technique(self, slot, spec):
        if not isinstance(spec, str) or not spec:
            raise DyngiError("'technique' needs a spec")
        self.techniques.append((slot, spec))


@pytest.fixture(params=[True, False], ids=["token", "no-token"])
def server(request):
    srv = ViewerServer(_StubSession(), "127.0.0.1", 0, token=request.param)
    th = threading.Thread(target=lambda: asyncio.run(srv.run()), daemon=True)
    th.start()
    assert srv.started.wait(10)
    yield srv
    srv.stop()
    th.join(10)


def _ws_url(srv, token: str | None = "own") -> str:
    t = srv.token if token == "own" else token
    return f"ws://127.0.0.1:{srv.bound_port}/ws" + (f"?token={t}" if t else "")


def _origin(srv) -> str:
    return f"http://127.0.0.1:{srv.bound_port}"


async def _first_message(url: str, origin: str | None, send: list | None = None, timeout: float = 5.0):
    """Open the websocket, send ``send``; the JSON messages received until ``timeout`` or close."""
    kw = {"origin": origin} if origin is not None else {}
    got = []
    async with connect(url, max_size=2 ** 25, **kw) as ws:
        for m in send or []:
            await ws.send(m)
        try:
            while True:
                raw = await asyncio.wait_for(ws.recv(), timeout)
                if isinstance(raw, str):
                    got.append(json.loads(raw))
                    if send and len(got) > len(send):
                        break
                    if not send:
                        break
        except (asyncio.TimeoutError, websockets.ConnectionClosed) as e:
            got.append(e)
    return got


def _handshake_status(url: str, origin: str | None) -> int:
    try:
        asyncio.run(_first_message(url, origin))
        return 101
    except websockets.InvalidStatus as e:
        return e.response.status_code


def test_own_page_connects_and_gets_the_state(server):
    got = asyncio.run(_first_message(_ws_url(server), _origin(server)))
    assert got and isinstance(got[0], dict) and got[0]["type"] == "state"


def test_foreign_origin_is_refused(server):
    """Another site's page, with or without the token (a leaked address), gets 403 and no state."""
    for origin in ("http://evil.example", "http://evil.example:%d" % server.bound_port, "null",
                   "https://127.0.0.1:%d" % server.bound_port):
        assert _handshake_status(_ws_url(server), origin) == 403, origin


def _raw_handshake(srv, host: str, origin: str) -> str:
    """The status line the server answers a websocket handshake with these ``Host`` and ``Origin``."""
    import socket

    with socket.create_connection(("127.0.0.1", srv.bound_port), timeout=5) as s:
        path = "/ws" + (f"?token={srv.token}" if srv.token else "")
        s.sendall((f"GET {path} HTTP/1.1\r\nHost: {host}\r\nOrigin: {origin}\r\nUpgrade: websocket\r\n"
                   "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                   "Sec-WebSocket-Version: 13\r\n\r\n").encode())
        return s.recv(4096).decode("latin-1").split("\r\n", 1)[0]


def test_rebinding_host_is_refused(server):
    """A page on a name that resolves to 127.0.0.1 (DNS rebinding) sends its own name as Host and Origin:
    the origin check passes, the loopback-Host check refuses it; the same handshake on 127.0.0.1 passes."""
    p = server.bound_port
    assert " 403 " in _raw_handshake(server, f"evil.example:{p}", f"http://evil.example:{p}")
    assert " 101 " in _raw_handshake(server, f"127.0.0.1:{p}", f"http://127.0.0.1:{p}")


def test_token_is_required_for_the_websocket_and_the_page(server):
    if server.token is None:
        assert server.url.endswith("/") and "token" not in server.url
        assert _handshake_status(_ws_url(server, None), _origin(server)) == 101
        return
    assert server.url.endswith(f"/?token={server.token}") and len(server.token) >= 32
    assert _handshake_status(_ws_url(server, None), _origin(server)) == 403           # missing
    assert _handshake_status(_ws_url(server, "x" + server.token[1:]), _origin(server)) == 403   # wrong
    assert _handshake_status(_ws_url(server, None), None) == 403                      # a script, no token
    assert _handshake_status(_ws_url(server), None) == 101                            # a script with it
    page = f"http://127.0.0.1:{server.bound_port}/"
    with pytest.raises(urllib.error.HTTPError) as e:
        urllib.request.urlopen(page, timeout=5)
    assert e.value.code == 403
    with urllib.request.urlopen(server.url, timeout=5) as r:
        assert r.status == 200 and f"dyngi-view-token={server.token}" in r.headers.get("Set-Cookie", "")
    # the page's cookie stands for the token (the browser sends it on the websocket handshake)
    async def with_cookie():
        async with connect(_ws_url(server, None), origin=_origin(server),
                           additional_headers={"Cookie": f"dyngi-view-token={server.token}"}) as ws:
            return json.loads(await asyncio.wait_for(ws.recv(), 5))
    assert asyncio.run(with_cookie())["type"] == "state"


def test_bad_messages_get_an_error_and_the_server_carries_on(server):
    bad = ["{not json", json.dumps([1, 2]), json.dumps({"type": "format-disk"}), b"\x00\x01"]
    got = asyncio.run(_first_message(_ws_url(server), _origin(server), send=bad, timeout=3.0))
    errors = [m for m in got if isinstance(m, dict) and m.get("type") == "error"]
    assert len(errors) >= 3, got
    text = " ".join(m["message"] for m in errors)
    assert "not JSON" in text and "unknown message type 'format-disk'" in text
    # a 10 MB message closes that connection (1009, message too big) ...
    async def huge():
        ws = await connect(_ws_url(server), origin=_origin(server), max_size=2 ** 25)
        await ws.recv()                           # the state
        try:
            await ws.send("x" * (10 * 2 ** 20))
        except websockets.ConnectionClosed:
            pass
        await asyncio.wait_for(ws.wait_closed(), 10)
        return ws.close_code
    assert asyncio.run(huge()) == 1009
    # ... and the server still answers a good command from a new page
    good = asyncio.run(_first_message(_ws_url(server), _origin(server),
                                      send=[json.dumps({"type": "technique", "slot": "a", "spec": "ddgi"})]))
    states = [m for m in good if isinstance(m, dict) and m.get("type") == "state"]
    assert states and ["a", "ddgi"] in [list(t) for t in states[-1]["techniques"]], good


def test_no_token_only_on_loopback():
    assert is_loopback("127.0.0.1") and is_loopback("localhost") and is_loopback("::1")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.168.1.5")
    with pytest.raises(DyngiError, match="--no-token is allowed only on a loopback"):
        ViewerServer(_StubSession(), "0.0.0.0", 0, token=False)
    assert ViewerServer(_StubSession(), "0.0.0.0", 0).token          # on by default
