"""Who may read the page (services.web.server.Access): real HTTP and WebSocket clients (aiohttp) against a
running :class:`WebServer` on loopback.

A page from another site in the operator's browser (a foreign ``Origin``), a DNS-rebinding host name
(a hostile ``Host`` resolving to 127.0.0.1) and any request without the printed token read nothing:
403 on the JSON routes, the previews and the WebSocket handshake. The token from the URL becomes a
cookie, so the page's own requests carry it.
"""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys

import aiohttp
import pytest

from protocol.scenario import load_scenario
from services.web.server import Access, WebServer, page_url
from services.web.view import FleetView

TOKEN = "t0ken-for-the-tests-0123456789"


@pytest.fixture
def server():
    view = FleetView(load_scenario(), fleet="f")
    view.on_preview(1, b"\xff\xd8jpeg")
    srv = WebServer(view, "127.0.0.1", 0, token=TOKEN, allowed_hosts=("inspect.example",)).start()
    yield srv
    srv.stop()


def run(coro):
    return asyncio.run(coro)


async def status(url: str, **kw) -> int:
    async with aiohttp.ClientSession() as s, s.get(url, **kw) as r:
        await r.read()
        return r.status


async def ws_first(url: str, **kw) -> dict | int:
    """The WebSocket's first message, or the handshake's refusal status."""
    async with aiohttp.ClientSession() as s:
        try:
            async with s.ws_connect(url, **kw) as ws:
                msg = await ws.receive(timeout=10)
                return json.loads(msg.data)
        except aiohttp.WSServerHandshakeError as exc:
            return exc.status


def test_no_token_or_a_wrong_one_reads_nothing(server) -> None:
    base = f"http://127.0.0.1:{server.port}"
    for path in ("/", "/app.js", "/snapshot.json", "/preview/1.jpg"):
        assert run(status(base + path)) == 403, path
        assert run(status(base + path + "?token=wrong-token-0123456789")) == 403, path
        assert run(status(base + path, headers={"Authorization": "token not-the-token-123456"})) == 403, path
    assert run(ws_first(f"ws://127.0.0.1:{server.port}/ws")) == 403
    assert server.refused >= 13


def test_the_token_serves_every_route_and_becomes_a_cookie(server) -> None:
    base = f"http://127.0.0.1:{server.port}"

    async def session() -> tuple[int, str, dict, dict]:
        # a browser keeps cookies of 127.0.0.1; aiohttp's jar does so only when told (unsafe=True)
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as s:
            async with s.get(server.url) as r:  # the printed URL
                page, csp = await r.text(), r.headers["Content-Security-Policy"]
                assert r.status == 200 and "SkyNet Inspect" in page
                cookie = r.headers["Set-Cookie"]
                assert "HttpOnly" in cookie and "SameSite=Strict" in cookie  # not for scripts, not cross-site
            # the page's own requests: the cookie only
            async with s.get(base + "/snapshot.json") as r:
                snap = await r.json()
            async with s.get(base + "/preview/1.jpg") as r:
                assert r.status == 200 and await r.read() == b"\xff\xd8jpeg"
            async with s.ws_connect(f"ws://127.0.0.1:{server.port}/ws",
                                    origin=f"http://127.0.0.1:{server.port}") as ws:
                first = json.loads((await ws.receive(timeout=10)).data)
            return r.status, csp, snap, first

    code, csp, snap, first = run(session())
    assert snap["type"] == "snapshot" and first["type"] == "static" and first["fleet"] == "f"
    assert "script-src 'self'" in csp and "frame-ancestors 'none'" in csp
    auth = {"Authorization": f"token {TOKEN}"}  # scripts
    assert run(status(base + "/snapshot.json", headers=auth)) == 200
    assert run(status(base + "/preview/7.jpg", headers=auth)) == 404  # no preview yet
    assert run(status(base + "/preview/" + "9" * 5000 + ".jpg", headers=auth)) == 404  # not a UAV number
    assert server.url == f"http://127.0.0.1:{server.port}/?token={TOKEN}"


def test_a_foreign_origin_is_refused_the_websocket_and_the_json(server) -> None:
    ws = f"ws://127.0.0.1:{server.port}/ws?token={TOKEN}"
    for origin in ("http://evil.example", f"http://evil.example:{server.port}", "null",
                   f"https://127.0.0.1:{server.port}", "http://127.0.0.1:1"):
        assert run(ws_first(ws, origin=origin)) == 403, origin
        assert run(status(f"http://127.0.0.1:{server.port}/snapshot.json?token={TOKEN}",
                          headers={"Origin": origin})) == 403, origin
    for name in ("127.0.0.1", "localhost"):  # the page's own origin: the host it was loaded from
        hp = f"{name}:{server.port}"
        assert run(ws_first(ws, origin=f"http://{hp}", headers={"Host": hp}))["type"] == "static", name
    # another origin of this machine (a page on localhost asking 127.0.0.1) is another site
    assert run(ws_first(ws, origin=f"http://localhost:{server.port}")) == 403


def test_a_rebinding_host_is_refused(server) -> None:
    """A hostile name resolving to 127.0.0.1 makes the browser send ``Host: rebind.evil:PORT`` (same origin
    for the browser, so no Origin check helps): refused; names the operator allows are served."""
    snap = f"http://127.0.0.1:{server.port}/snapshot.json?token={TOKEN}"
    bad = f"rebind.evil:{server.port}"
    assert run(status(snap, headers={"Host": bad})) == 403
    assert run(ws_first(f"ws://127.0.0.1:{server.port}/ws?token={TOKEN}", headers={"Host": bad},
                        origin=f"http://{bad}")) == 403
    for good in (f"localhost:{server.port}", f"127.0.0.1:{server.port}", f"inspect.example:{server.port}"):
        assert run(status(snap, headers={"Host": good})) == 200, good


def test_access_rules() -> None:
    a = Access("127.0.0.1", 8080, TOKEN)
    assert a.host_ok("127.0.0.1:8080") and a.host_ok("LOCALHOST:8080") and a.host_ok("[::1]:8080")
    assert not a.host_ok(None) and not a.host_ok("") and not a.host_ok("127.0.0.1.evil:8080")
    assert a.origin_ok(None) and a.origin_ok("http://localhost:8080") and a.origin_ok("http://[::1]:8080")
    assert not a.origin_ok("http://localhost:8081") and not a.origin_ok("http://localhost") and not a.origin_ok("file://")
    assert not a.origin_ok("http://[bad") and not a.origin_ok("http://localhost:99999")
    # behind a published port (a container's 8080 on the host's 18080): Origin and Host agree, the port is theirs
    assert a.origin_ok("http://127.0.0.1:18080", "127.0.0.1:18080")
    assert not a.origin_ok("http://127.0.0.1:18080", "127.0.0.1:8080")
    assert not a.origin_ok("http://localhost:8080", "127.0.0.1:8080")  # another origin of the same machine
    assert a.token_ok(TOKEN, None, None) and a.token_ok(None, TOKEN, None) and a.token_ok(None, None, f"Bearer {TOKEN}")
    assert not a.token_ok(None, None, None) and not a.token_ok(TOKEN[:-1], None, None)
    assert a.refusal("127.0.0.1:8080", None, None, TOKEN, None) is None
    assert "access token" in a.refusal("127.0.0.1:8080", None, None, None, None)
    lan = Access("192.168.1.5", 8080, TOKEN)  # bound to a LAN address: that address too
    assert lan.host_ok("192.168.1.5:8080") and not lan.host_ok("192.168.1.6:8080")
    with pytest.raises(ValueError, match="16 characters"):
        Access("127.0.0.1", 8080, "short")
    assert page_url("0.0.0.0", 80, TOKEN) == f"http://127.0.0.1:80/?token={TOKEN}"
    assert page_url("::1", 80, TOKEN) == f"http://[::1]:80/?token={TOKEN}"


def test_a_short_token_is_a_one_line_error() -> None:
    p = subprocess.run([sys.executable, "-m", "services.cli", "web", "--token", "short"], capture_output=True,
                       text=True, timeout=60)
    assert p.returncode == 2 and "at least 16 characters" in p.stderr and "Traceback" not in p.stderr


def test_a_refusal_is_logged_on_one_line_without_terminal_escapes(server, caplog) -> None:
    caplog.set_level("WARNING", logger="services.web.server")
    assert run(status(f"http://127.0.0.1:{server.port}/%1b]0;pwned%07%0d%0aforged")) == 403
    lines = [r.getMessage() for r in caplog.records if "refused" in r.getMessage()]
    assert lines and all("\x1b" not in m and "\x07" not in m and "\n" not in m for m in lines), lines
