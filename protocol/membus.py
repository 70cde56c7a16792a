"""An in-memory twin of the bus: :class:`MemBus` is a :class:`protocol.bus.Bus` whose Zenoh session is
replaced by :class:`MemSession`, a stand-in that delivers in this process, synchronously, in the caller's thread.

Design notes: docs/bus.md (protocol/membus.py).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import zenoh

from . import keys
from .bus import Bus, BusConfig, Counters, Publisher
from .links import LinkClass


class _Payload:
    """A sample's payload: what :class:`zenoh.ZBytes` offers the bus layer."""

    __slots__ = ("_data",)

    def __init__(self, data: bytes | None) -> None:
        self._data = bytes(data or b"")

    def to_bytes(self) -> bytes:
        return self._data

    def __len__(self) -> int:
        return len(self._data)


class MemSample:
    """A delivered sample: key, payload, kind (``PUT`` or ``DELETE`` for liveliness), attachment."""

    __slots__ = ("key_expr", "payload", "kind", "attachment", "encoding")

    def __init__(self, key_expr: str, payload: _Payload, kind: Any = None, attachment: _Payload | None = None,
                 encoding: Any = None) -> None:
        self.key_expr, self.payload, self.attachment, self.encoding = key_expr, payload, attachment, encoding
        self.kind = zenoh.SampleKind.PUT if kind is None else kind


@dataclass(frozen=True)
class _Ok:
    key_expr: str
    payload: _Payload


@dataclass(frozen=True)
class MemReply:
    """A query's answer: ``ok`` (key and payload) or ``err`` (payload), as :class:`zenoh.Reply`."""

    ok: _Ok | None = None
    err: _Ok | None = None


class MemQuery:
    """What a queryable's callback gets (:class:`zenoh.Query`): the key, the payload, reply and reply_err."""

    def __init__(self, key: str, payload: bytes | None) -> None:
        self.key_expr = key
        self.payload = None if payload is None else _Payload(payload)
        self.replies: list[MemReply] = []

    def reply(self, key_expr: str, payload: bytes, encoding: Any = None) -> None:
        self.replies.append(MemReply(ok=_Ok(str(key_expr), _Payload(payload))))

    def reply_err(self, payload: bytes, encoding: Any = None) -> None:
        self.replies.append(MemReply(err=_Ok(self.key_expr, _Payload(payload))))

    def drop(self) -> None:
        pass


def intersects(a: str, b: str) -> bool:
    """Whether two key expressions share a key (Zenoh's rule: ``*`` one chunk, ``**`` any number)."""
    return zenoh.KeyExpr(a).intersects(zenoh.KeyExpr(b))


class _Entity:
    """A declared subscriber, queryable, token or liveliness subscriber; ``undeclare`` removes it."""

    def __init__(self, table: list[Any], session: MemSession, key: str, target: Any = None) -> None:
        self.table, self.session, self.key, self.target = table, session, key, target

    def undeclare(self) -> None:
        self.session.net.undeclare(self)


class _MemPublisher:
    def __init__(self, session: MemSession, key: str) -> None:
        self.session, self.key = session, key

    def put(self, data: bytes, encoding: Any = None, attachment: bytes | None = None) -> None:
        self.session.net.put(self.session, self.key, data, attachment)

    @property
    def matching_status(self) -> Any:
        return _Matching(self.session.net.has_subscriber(self.key, self.session))

    def undeclare(self) -> None:
        pass


@dataclass(frozen=True)
class _Matching:
    matching: bool


class _Liveliness:
    def __init__(self, session: MemSession) -> None:
        self.session = session

    def declare_token(self, key: str) -> _Entity:
        return self.session.net.declare_token(self.session, key)

    def declare_subscriber(self, key: str, handler: Callable[..., Any], history: bool = False) -> _Entity:
        return self.session.net.declare_alive_watch(self.session, key, handler, history)

    def get(self, key: str, timeout: float = 1.0) -> list[MemReply]:
        return [MemReply(ok=_Ok(k, _Payload(b""))) for k in self.session.net.tokens(key)]


class _Info:
    def __init__(self, session: MemSession) -> None:
        self.session = session

    def links(self) -> list[Any]:
        return []

    def peers_zid(self) -> list[str]:
        return [s.name for s in self.session.net.sessions() if s is not self.session]

    def routers_zid(self) -> list[str]:
        return []


class MemSession:
    """The part of :class:`zenoh.Session` that :class:`~protocol.bus.Bus` uses, on a :class:`MemNetwork`."""

    def __init__(self, net: MemNetwork, name: str) -> None:
        self.net, self.name = net, name
        self.info = _Info(self)
        self.closed = False

    def declare_publisher(self, key: str, **qos: Any) -> _MemPublisher:
        return _MemPublisher(self, key)

    def declare_subscriber(self, key: str, handler: Callable[..., Any]) -> _Entity:
        return self.net.declare(self.net.subscribers, self, key, handler)

    def declare_queryable(self, key: str, handler: Callable[..., Any]) -> _Entity:
        return self.net.declare(self.net.queryables, self, key, handler)

    def get(self, key: str, payload: bytes | None = None, handler: Any = None, **options: Any) -> Iterator[MemReply]:
        replies = self.net.query(self, key, payload)
        if options.get("target") is None and replies:  # the consolidated answer: one
            replies = replies[:1]
        if handler is None:
            return iter(replies)
        on_reply, on_end = _callbacks(handler)
        for r in replies:
            on_reply(r)
        if on_end is not None:
            on_end()
        return iter(())

    def liveliness(self) -> _Liveliness:
        return _Liveliness(self)

    def close(self) -> None:
        self.net.drop(self)


def _callbacks(handler: Any) -> tuple[Callable[..., Any], Callable[..., Any] | None]:
    """The callables of a reply handler: a plain callable, or a ``zenoh.handlers.Callback`` (its callback
    and drop)."""
    if isinstance(handler, zenoh.handlers.Callback):
        return handler.callback, handler.drop
    return handler, None


class MemNetwork:
    """The shared medium of :class:`MemSession` s: who subscribes, answers and holds which token."""

    def __init__(self) -> None:
        self.subscribers: list[_Entity] = []
        self.queryables: list[_Entity] = []
        self.alive_tokens: list[_Entity] = []
        self.alive_watches: list[_Entity] = []
        self._sessions: list[MemSession] = []
        self._lock = threading.RLock()

    def session(self, name: str) -> MemSession:
        s = MemSession(self, name)
        with self._lock:
            self._sessions.append(s)
        return s

    def sessions(self) -> list[MemSession]:
        with self._lock:
            return list(self._sessions)

    # -- declarations
    def declare(self, table: list[Any], session: MemSession, key: str, target: Any = None) -> _Entity:
        e = _Entity(table, session, str(key), target)
        with self._lock:
            table.append(e)
        return e

    def undeclare(self, e: _Entity) -> None:
        with self._lock:
            if e not in e.table:
                return
            e.table.remove(e)
        if e.table is self.alive_tokens:
            self._announce(e.key, zenoh.SampleKind.DELETE)

    def declare_token(self, session: MemSession, key: str) -> _Entity:
        e = self.declare(self.alive_tokens, session, key)
        self._announce(key, zenoh.SampleKind.PUT)
        return e

    def declare_alive_watch(self, session: MemSession, key: str, handler: Callable[..., Any], history: bool) -> _Entity:
        e = self.declare(self.alive_watches, session, key, handler)
        if history:
            for k in self.tokens(key):
                handler(MemSample(k, _Payload(b"")))
        return e

    def tokens(self, key: str) -> list[str]:
        with self._lock:
            return sorted({t.key for t in self.alive_tokens if intersects(t.key, key)})

    def has_subscriber(self, key: str, other_than: MemSession | None = None) -> bool:
        with self._lock:
            return any(intersects(e.key, key) for e in self.subscribers if e.session is not other_than)

    # -- traffic (delivered in the caller's thread, outside the lock: a callback may publish)
    def put(self, session: MemSession, key: str, data: bytes, attachment: bytes | None = None) -> None:
        if session.closed:
            return
        with self._lock:
            targets = [e.target for e in self.subscribers if intersects(e.key, key)]
        sample = MemSample(key, _Payload(data), attachment=None if attachment is None else _Payload(attachment))
        for cb in targets:
            cb(sample)

    def query(self, session: MemSession, key: str, payload: bytes | None) -> list[MemReply]:
        if session.closed:
            return []
        with self._lock:
            targets = [e.target for e in self.queryables if intersects(e.key, key)]
        out: list[MemReply] = []
        for cb in targets:
            q = MemQuery(key, payload)
            cb(q)
            out.extend(q.replies)
        return out

    def _announce(self, key: str, kind: zenoh.SampleKind) -> None:
        with self._lock:
            targets = [e.target for e in self.alive_watches if intersects(e.key, key)]
        for cb in targets:
            cb(MemSample(key, _Payload(b""), kind=kind))

    def drop(self, session: MemSession) -> None:
        """Cut ``session`` off: its declarations go, its tokens leave (the others see them lost)."""
        session.closed = True
        with self._lock:
            if session in self._sessions:
                self._sessions.remove(session)
            gone = [e for table in (self.subscribers, self.queryables, self.alive_tokens, self.alive_watches)
                    for e in table if e.session is session]
        for e in gone:
            self.undeclare(e)


class MemBus(Bus):
    """A :class:`~protocol.bus.Bus` on a :class:`MemNetwork` instead of a Zenoh session."""

    def __init__(self, net: MemNetwork | None = None, fleet: str = keys.DEFAULT_FLEET, name: str = "node") -> None:
        self.net = net or MemNetwork()
        self.config = BusConfig()
        self.fleet, self.name = fleet, name
        self.counters = Counters()
        self.session = self.net.session(name)  # type: ignore[assignment]  # the in-memory twin of zenoh.Session
        self._entities = []
        self._rings = []
        self._closed = False
        self._close_lock = threading.Lock()

    def publisher(self, key: str, link: LinkClass, cache: int | None = None) -> Publisher:
        """A publisher; ``cache`` is ignored (nothing is lost in memory)."""
        return Publisher(self, key, link, None)

    def subscribe_raw(self, key: str, callback: Callable[..., Any], ring: int | None = None, recover: bool = False) -> Any:
        """As :meth:`Bus.subscribe_raw`; ``recover`` changes nothing (nothing is lost in memory)."""
        return super().subscribe_raw(key, callback, ring=ring, recover=False)
