"""The MAVLink link: a pymavlink connection speaking MAVLink 2, optionally signed, with a reader thread.

Design notes: docs/hardware-mavlink.md (edge/vehicle/mavlink/link.py).
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable
from typing import Any

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as M

from edge.vehicle.apm.signing import SafeSigningMAVLink, enable_signing, parse_key

__all__ = ["Link", "open_connection"]


class _Clients(set):
    """pymavlink's ``udpin:`` peer set, iterated over a snapshot taken under the lock of every change (why:
    docs/hardware-mavlink.md, edge/vehicle/mavlink/link.py)."""

    def __init__(self, *args) -> None:
        super().__init__(*args)
        self._lock = threading.Lock()

    def add(self, item) -> None:
        with self._lock:
            set.add(self, item)

    def discard(self, item) -> None:
        with self._lock:
            set.discard(self, item)

    def remove(self, item) -> None:
        with self._lock:
            set.remove(self, item)

    def __isub__(self, other):
        with self._lock:
            set.difference_update(self, other)
        return self

    def __iter__(self):
        with self._lock:
            snapshot = set.copy(self)
        return iter(snapshot)


def open_connection(connection: str, source_system: int, source_component: int) -> Any:
    """A pymavlink connection (``udpin:``, ``udpout:``, ``tcp:``, serial, ...) speaking MAVLink 2.

    The connection's encoder is replaced by the MAVLink 2 ``ardupilotmega`` one, so the wire
    version does not depend on the ``MAVLINK20`` environment variable at import time.
    """
    if not isinstance(connection, str) or not connection.strip():
        raise ValueError("connection must be a pymavlink connection string, e.g. 'udpin:0.0.0.0:14550'")
    for v, name in ((source_system, "source_system"), (source_component, "source_component")):
        if not (isinstance(v, int) and 0 <= v <= 255):
            raise ValueError(f"{name} must be an int in 0..255")
    try:
        conn = mavutil.mavlink_connection(connection, source_system=source_system, source_component=source_component)
    except Exception as exc:  # pymavlink raises OSError, ValueError, serial errors, ...
        raise ValueError(f"cannot open MAVLink connection {connection!r}: {exc}") from exc
    conn.mav = SafeSigningMAVLink(conn, srcSystem=source_system, srcComponent=source_component)
    conn.mav.robust_parsing = True
    if isinstance(getattr(conn, "clients", None), set):
        conn.clients = _Clients(conn.clients)
    conn.WIRE_PROTOCOL_VERSION = "2.0"
    return conn


class Link:
    """A connection (:func:`open_connection`, signed with ``signing_key``) and its reader thread."""

    def __init__(self, connection: str, source_system: int, source_component: int, *, name: str,
                 hb_type: int, on_message: Callable[[Any, float], None], on_tick: Callable[[float], None],
                 signing_key: str | None = None):
        self.conn = open_connection(connection, source_system, source_component)
        if signing_key is not None:
            enable_signing(self.conn, parse_key(signing_key))
        self.hb_type = hb_type
        self.errors = 0
        self._on_message, self._on_tick = on_message, on_tick
        self._send_lock = threading.Lock()
        self._stop = threading.Event()
        self._reader = threading.Thread(target=self._loop, name=name, daemon=True)

    def start(self) -> None:
        self._reader.start()

    @property
    def our_system(self) -> int:
        return self.conn.mav.srcSystem

    def send(self, msg: Any) -> None:
        """Send one message (encoded and signed by the connection)."""
        with self._send_lock:
            try:
                self.conn.mav.send(msg)
            except OSError:
                self.errors += 1

    def write(self, frame: bytes) -> None:
        """One raw frame (from the ground-station bridge)."""
        with self._send_lock:
            self.conn.write(frame)

    def _loop(self) -> None:
        last_hb, heard = -math.inf, False
        while not self._stop.is_set():
            try:
                msg = self.conn.recv_msg()
            except Exception:  # a malformed datagram or a closed socket must not kill the reader
                if self._stop.is_set():
                    break
                self.errors += 1
                msg = None
            now = time.monotonic()
            if msg is not None:
                if not heard:  # the first packet: a udpin link can answer now, so say we are here at once
                    heard, last_hb = True, -math.inf
                self._on_message(msg, now)
            else:
                self.conn.select(0.02)
            if now - last_hb >= 1.0:
                last_hb = now
                self.send(M.MAVLink_heartbeat_message(self.hb_type, M.MAV_AUTOPILOT_INVALID, 0, 0,
                                                      M.MAV_STATE_ACTIVE, 3))
            self._on_tick(now)

    def close(self) -> None:
        self._stop.set()
        if self._reader.is_alive():
            self._reader.join(timeout=2.0)
        with contextlib.suppress(OSError):
            self.conn.close()
