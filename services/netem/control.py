"""The control channel of a running proxy: text commands over loopback UDP, JSON replies.

Design notes: docs/experiments.md (services/netem/control.py).
"""

from __future__ import annotations

import contextlib
import json
import selectors
import socket
import threading
from typing import Any

from protocol import codec
from services.netem.proxy import _MAX_DATAGRAM, Address, _check_address, _ProxyBase, _resolve, format_address

__all__ = ["ControlServer", "send_control"]


def _is_loopback(addr: Address) -> bool:
    import ipaddress

    try:
        infos = socket.getaddrinfo(addr[0], addr[1], type=socket.SOCK_DGRAM)
    except socket.gaierror:
        return False
    return bool(infos) and all(ipaddress.ip_address(info[4][0]).is_loopback for info in infos)


class ControlServer:
    """A text control channel for one proxy: UDP datagrams on loopback, one command per datagram
    (the grammar of :mod:`services.netem.schedule`: ``set SPEC``, ``cut [T]``, ``restore``,
    ``clear``, ``stats``), one JSON reply each: ``{"ok": true, ...}`` or ``{"ok": false,
    "error": "..."}``. A bad command gets an error reply and changes nothing; nothing a client
    sends stops the proxy. Loopback only: the channel has no authentication."""

    def __init__(self, proxy: _ProxyBase, listen: Address | str = ("127.0.0.1", 0)) -> None:
        self.proxy = proxy
        self.listen = _check_address(listen, "control address")
        if not _is_loopback(self.listen):
            raise ValueError(f"control address {format_address(self.listen)}: must be a loopback address "
                             "(the channel has no authentication)")
        self.requests = self.errors = 0
        self._address: Address | None = None
        self._thread: threading.Thread | None = None

    @property
    def address(self) -> Address:
        if self._address is None:
            raise RuntimeError("ControlServer not started")
        return self._address

    def start(self) -> ControlServer:
        if self._thread is not None:
            raise RuntimeError("ControlServer already started")
        fam, sa = _resolve(self.listen, socket.SOCK_DGRAM)
        self._sock = socket.socket(fam, socket.SOCK_DGRAM)
        try:
            self._sock.bind(sa)
        except OSError:
            self._sock.close()
            raise
        self._address = (self.listen[0], self._sock.getsockname()[1])
        self._wake_r, self._wake_w = socket.socketpair()
        self._running = True
        self._thread = threading.Thread(target=self._run, name=f"netem-ctl-{self._address[1]}", daemon=True)
        self._thread.start()
        return self

    def handle(self, text: str) -> dict[str, Any]:
        """The reply to one command (never raises)."""
        self.requests += 1
        try:
            return self.proxy.apply(text)
        except (ValueError, RuntimeError) as e:
            self.errors += 1
            return {"ok": False, "error": " ".join(str(e).split())}
        except Exception as e:  # noqa: BLE001 - a control request must never end the proxy
            self.errors += 1
            return {"ok": False, "error": f"{type(e).__name__}: {e}"}

    def _run(self) -> None:
        with selectors.DefaultSelector() as sel:
            sel.register(self._sock, selectors.EVENT_READ, "ctl")
            sel.register(self._wake_r, selectors.EVENT_READ, "wake")
            while self._running:
                for key, _ in sel.select():
                    if key.data == "wake" or not self._running:
                        return
                    try:
                        data, peer = self._sock.recvfrom(_MAX_DATAGRAM)
                    except OSError:
                        continue
                    try:
                        reply = self.handle(data.decode("utf-8"))
                    except UnicodeDecodeError:
                        self.requests += 1
                        self.errors += 1
                        reply = {"ok": False, "error": "a command is UTF-8 text"}
                    with contextlib.suppress(OSError):
                        self._sock.sendto(json.dumps(reply).encode(), peer)

    def stop(self) -> None:
        """Join the thread and close the socket. Idempotent."""
        if self._thread is None or not self._running:
            return
        self._running = False
        with contextlib.suppress(OSError):
            self._wake_w.send(b"x")
        self._thread.join()
        for s in (self._sock, self._wake_r, self._wake_w):
            s.close()

    def __enter__(self) -> ControlServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def send_control(address: Address | str, command: str, timeout_s: float = 3.0) -> dict[str, Any]:
    """Send one command to a :class:`ControlServer` and return its JSON reply.

    Raises :class:`TimeoutError` when no reply comes within ``timeout_s`` (one try: commands
    such as ``cut`` are not idempotent), :class:`OSError` on socket errors.
    """
    addr = _check_address(address, "control address")
    fam, sa = _resolve(addr, socket.SOCK_DGRAM)
    with socket.socket(fam, socket.SOCK_DGRAM) as s:
        s.settimeout(timeout_s)
        s.connect(sa)
        s.send(command.encode("utf-8"))
        try:
            data = s.recv(_MAX_DATAGRAM)
        except TimeoutError as e:
            raise TimeoutError(f"no reply from {format_address(addr)} within {timeout_s} s") from e
    return codec.loads_json(data)  # the reply of a process on that address: deep nesting is a ValueError
