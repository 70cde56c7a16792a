"""The web server of the fleet view (aiohttp): the page, the previews, a WebSocket pushing snapshots.

Design notes: docs/operator-view.md (services/web/server.py).
"""

from __future__ import annotations

import asyncio
import hmac
import json
import logging
import secrets
import threading
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import urlsplit

from aiohttp import WSMsgType, web

from .view import FleetView

if TYPE_CHECKING:
    from .tally import DefectTally

STATIC = Path(__file__).with_name("static")
log = logging.getLogger(__name__)

#: environment variable that hands a process its page token (not on the command line, where ``ps`` shows it)
TOKEN_ENV = "SKYNET_WEB_TOKEN"
#: host names every page answers to besides its bound address
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")
_WILDCARD = ("", "0.0.0.0", "::")


def new_token() -> str:
    """A random access token (192 bits, URL-safe)."""
    return secrets.token_urlsafe(24)


def _host_name(host: str) -> str:
    """``"[::1]:8080"`` -> ``"::1"``, ``"Example.COM:80"`` -> ``"example.com"``, ``"h"`` -> ``"h"``."""
    host = host.strip().lower()
    if host.startswith("["):
        end = host.find("]")
        return host[1:end] if end > 0 else host
    name, sep, port = host.rpartition(":")
    return name if sep and port.isdigit() and ":" not in name else host


def page_url(host: str, port: int, token: str) -> str:
    """The URL the operator opens: loopback shown as ``127.0.0.1``, IPv6 bracketed, the token in the query."""
    shown = "127.0.0.1" if host in _WILDCARD else host
    if ":" in shown:
        shown = f"[{shown}]"
    return f"http://{shown}:{port}/?token={token}"


class Access:
    """Who may read the page (docs/operator-view.md): the ``Host``, ``Origin`` and token checks. Pure.

    ``host`` is the bound address; ``allowed_hosts`` more names the page answers to (a name the operator
    reaches it by, for instance through an SSH tunnel or on a LAN with a non-loopback ``host``).
    """

    def __init__(self, host: str, port: int, token: str, allowed_hosts: Iterable[str] = ()):
        if not token or len(token) < 16:
            raise ValueError("the page's access token must be at least 16 characters")
        self.token, self.port = token, int(port)
        names = {*LOOPBACK_NAMES, *(h.strip().lower() for h in allowed_hosts if h.strip())}
        if host not in _WILDCARD:
            names.add(_host_name(host))
        self.hosts = frozenset(names)
        self.cookie = f"skynet-token-{self.port}"  # one per port: two pages on one machine keep their own

    def host_ok(self, host: str | None) -> bool:
        return bool(host) and _host_name(host) in self.hosts

    def origin_ok(self, origin: str | None, host: str | None = None) -> bool:
        """No ``Origin`` (a script, not a browser page), or this page's own: ``http://`` and the ``Host`` the
        request was sent to (name and port; behind a published container port the port is the outside one)."""
        if origin is None:
            return True
        try:
            o = urlsplit(origin)
            h = urlsplit("//" + (host or ""))
            o_port, h_port = o.port or 80, h.port or 80
        except ValueError:
            return False
        return (o.scheme == "http" and o.hostname is not None and o.hostname.lower() in self.hosts
                and (h.hostname is None or (o.hostname.lower() == h.hostname.lower() and o_port == h_port))
                and (host is not None or o_port == self.port))

    def token_ok(self, query: str | None, cookie: str | None, header: str | None) -> bool:
        given = query or cookie
        if not given and header:
            scheme, _, value = header.partition(" ")
            given = value.strip() if scheme.lower() in ("token", "bearer") else None
        return given is not None and given != "" and hmac.compare_digest(given.encode(), self.token.encode())

    def refusal(self, host: str | None, origin: str | None, query: str | None, cookie: str | None,
                header: str | None) -> str | None:
        """Why a request is refused (one line), or None when it may be served."""
        if not self.host_ok(host):
            return f"Host {host!r} is not one this page answers to"
        if not self.origin_ok(origin, host):
            return f"Origin {origin!r} is not this page's"
        if not self.token_ok(query, cookie, header):
            return "no valid access token: open the URL the server printed (with ?token=...)"
        return None


def parse_listen(spec: str) -> tuple[str, int]:
    """``":8080"`` -> ``("127.0.0.1", 8080)``; ``"HOST:PORT"``; loopback unless a host is given."""
    host, sep, port = str(spec).rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) < 65536:
        raise ValueError(f"--web wants [HOST]:PORT, got {spec!r}")
    return host or "127.0.0.1", int(port)


class WebServer:
    def __init__(self, view: FleetView, host: str = "127.0.0.1", port: int = 8080, rate_hz: float = 10.0,
                 token: str | None = None, allowed_hosts: Iterable[str] = ()):
        if not 1.0 <= rate_hz <= 30.0:
            raise ValueError(f"web update rate must be in 1..30 Hz, got {rate_hz!r}")
        self.view, self.host, self.port, self.period_s = view, host, int(port), 1.0 / rate_hz
        self.token = token or new_token()
        self.allowed_hosts = tuple(allowed_hosts)
        self.access = Access(host, self.port, self.token, self.allowed_hosts)
        self.refused = 0  # requests refused by the access checks
        self.tally: DefectTally | None = None  # when the page counts defects as the report does
        self.on_stop: Callable[[], None] | None = None  # called by stop()
        self.sent = 0  # snapshots sent, all clients
        self.clients = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._stop: asyncio.Event | None = None
        self._error: BaseException | None = None
        self._snapshot: tuple[float, str] | None = None  # (built at, JSON): shared by every page of a period

    @property
    def url(self) -> str:
        """The page's URL with its token (what the operator opens)."""
        return page_url(self.host, self.port, self.token)

    @web.middleware
    async def _guard(self, request: web.Request, handler) -> web.StreamResponse:
        h = request.headers
        reason = self.access.refusal(h.get("Host"), h.get("Origin"), request.query.get("token"),
                                     request.cookies.get(self.access.cookie), h.get("Authorization"))
        if reason is not None:
            self.refused += 1
            if self.refused <= 10 or self.refused % 1000 == 0:
                log.warning("web: refused %s %r (%s; %d refused so far)", request.method, request.path, reason,
                            self.refused)
            return web.Response(status=403, text=reason + "\n")
        response = await handler(request)
        if response.prepared:  # a WebSocket, already answered
            return response
        response.headers["Content-Security-Policy"] = (
            "default-src 'none'; script-src 'self'; connect-src 'self' ws://" + h["Host"] + "; img-src 'self'; "
            "style-src 'self' 'unsafe-inline'; frame-ancestors 'none'; base-uri 'none'; form-action 'none'")
        response.headers["X-Content-Type-Options"] = "nosniff"
        response.headers["Referrer-Policy"] = "no-referrer"  # the token in the URL is not passed on
        if request.query.get("token"):
            response.set_cookie(self.access.cookie, self.token, httponly=True, samesite="Strict", path="/")
        return response

    def app(self) -> web.Application:
        app = web.Application(middlewares=[self._guard])
        app.add_routes([web.get("/", self._index), web.get("/app.js", self._js), web.get("/ws", self._ws),
                        web.get("/preview/{uav:\\d{1,3}}.jpg", self._preview), web.get("/snapshot.json", self._snap)])
        return app

    async def _index(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / "index.html")

    async def _js(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / "app.js", headers={"Content-Type": "text/javascript"})

    async def _preview(self, request: web.Request) -> web.StreamResponse:
        jpeg = self.view.preview(int(request.match_info["uav"]))
        if jpeg is None:
            raise web.HTTPNotFound(text="no preview yet")
        return web.Response(body=jpeg, content_type="image/jpeg", headers={"Cache-Control": "no-store"})

    async def _snap(self, request: web.Request) -> web.StreamResponse:
        return web.json_response(self.view.snapshot())

    def _snapshot_text(self, now: float) -> str:
        """The fleet's snapshot as JSON, built once per period for every page (the event loop's thread only)."""
        cached = self._snapshot
        if cached is None or now - cached[0] >= 0.5 * self.period_s:
            cached = self._snapshot = (now, json.dumps(self.view.snapshot()))
        return cached[1]

    async def _ws(self, request: web.Request) -> web.StreamResponse:
        ws = web.WebSocketResponse(heartbeat=10.0)
        await ws.prepare(request)
        self.clients += 1

        async def drain() -> None:  # the client sends nothing we need; read so that close frames are seen
            async for msg in ws:
                if msg.type == WSMsgType.ERROR:
                    break

        reader = asyncio.ensure_future(drain())
        version = -1
        try:
            loop = asyncio.get_running_loop()
            next_t = loop.time()
            while not ws.closed and not reader.done():
                if self.view.static_version != version:
                    doc = self.view.static()
                    version = doc["version"]
                    await ws.send_str(json.dumps(doc))
                await ws.send_str(self._snapshot_text(loop.time()))
                self.sent += 1
                next_t += self.period_s
                await asyncio.sleep(max(0.0, next_t - loop.time()))
        except (ConnectionResetError, RuntimeError):
            pass  # the page went away
        finally:
            reader.cancel()
            self.clients -= 1
        return ws

    # -- thread
    def start(self) -> WebServer:
        self._thread = threading.Thread(target=self._run, name="web", daemon=True)
        self._thread.start()
        self._ready.wait(15)
        if self._error is not None:
            raise self._error
        return self

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            loop.run_until_complete(self._serve())
        except BaseException as exc:  # noqa: BLE001 - reported to start()
            self._error = exc
            self._ready.set()
        finally:
            loop.close()

    async def _serve(self) -> None:
        self._stop = asyncio.Event()
        runner = web.AppRunner(self.app(), access_log=None)
        await runner.setup()
        site = web.TCPSite(runner, self.host, self.port)
        await site.start()
        self.port = runner.addresses[0][1]  # the real port when 0 was asked for
        self.access = Access(self.host, self.port, self.token, self.allowed_hosts)
        self._ready.set()
        await self._stop.wait()
        await runner.cleanup()

    def stop(self) -> None:
        if self.on_stop is not None:
            self.on_stop()
        if self._loop is not None and self._stop is not None and self._thread and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop.set)
            self._thread.join(10)
