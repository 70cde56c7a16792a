"""The web server of the fleet view (aiohttp): the page, the previews, a WebSocket pushing snapshots.

Routes:

- ``GET /`` the page (``static/index.html``, plain JavaScript, no build step), ``GET /app.js``;
- ``GET /preview/<uav>.jpg`` the newest preview JPEG of a UAV (404 before the first);
- ``GET /ws`` a WebSocket (RFC 6455): the server sends the static document on connect and when it
  changes, then a snapshot every ``1 / rate`` s (5–10 Hz); the client sends nothing;
- ``GET /snapshot.json`` one snapshot (for scripts and tests).

:class:`WebServer` runs the aiohttp application on its own thread and event loop, so the ground
station (a synchronous program) starts it with :meth:`start` and ends it with :meth:`stop`.
"""

from __future__ import annotations

import asyncio
import json
import threading
from pathlib import Path

from aiohttp import WSMsgType, web

from .view import FleetView

STATIC = Path(__file__).with_name("static")


def parse_listen(spec: str) -> tuple[str, int]:
    """``":8080"`` -> ``("127.0.0.1", 8080)``; ``"HOST:PORT"``; loopback unless a host is given."""
    host, sep, port = str(spec).rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) < 65536:
        raise ValueError(f"--web wants [HOST]:PORT, got {spec!r}")
    return host or "127.0.0.1", int(port)


class WebServer:
    def __init__(self, view: FleetView, host: str = "127.0.0.1", port: int = 8080, rate_hz: float = 10.0):
        if not 1.0 <= rate_hz <= 30.0:
            raise ValueError(f"web update rate must be in 1..30 Hz, got {rate_hz!r}")
        self.view, self.host, self.port, self.period_s = view, host, int(port), 1.0 / rate_hz
        self.sent = 0  # snapshots sent, all clients
        self.clients = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._stop: asyncio.Event | None = None
        self._error: BaseException | None = None
        self._snapshot: tuple[float, str] | None = None  # (built at, JSON): shared by every page of a period

    def app(self) -> web.Application:
        app = web.Application()
        app.add_routes([web.get("/", self._index), web.get("/app.js", self._js), web.get("/ws", self._ws),
                        web.get("/preview/{uav:\\d+}.jpg", self._preview), web.get("/snapshot.json", self._snap)])
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
    def start(self) -> "WebServer":
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
        self._ready.set()
        await self._stop.wait()
        await runner.cleanup()

    def stop(self) -> None:
        if self._loop is not None and self._stop is not None and self._thread and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop.set)
            self._thread.join(10)
