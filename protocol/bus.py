"""The bus layer: Zenoh sessions from a typed config, typed pub/sub by link class,
request/reply with acknowledgement semantics, liveliness, and clean shutdown.

Design notes: docs/bus.md (protocol/bus.py).
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import json
import logging
import os
import queue
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import zenoh
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, PlainSerializer, field_validator

from . import codec, keys
from .budget import Budget
from .cliconfig import Cli, CliModel, add_options, from_namespace
from .links import COMMAND, LinkClass
from .messages import ErrorReply, Message
from .ring import Ring as Ring  # services take their rings from the bus
from .signals import STOP_SIGNALS as STOP_SIGNALS  # the services' stop
from .signals import stop_event_on_signals as stop_event_on_signals
from .signals import stopping_on_signals as stopping_on_signals

log = logging.getLogger("skynet.bus")

#: period of the sequence-number heartbeat of publishers that keep a recovery cache, s
RECOVERY_HEARTBEAT_S = 0.5

Mode = Literal["peer", "client", "router"]


# ----------------------------------------------------------------------------- configuration
class BusConfig(BaseModel):
    """Everything needed to open a session; turned into a ``zenoh.Config`` by :meth:`to_zenoh`."""

    model_config = ConfigDict(extra="forbid")
    mode: Mode = "peer"
    listen: list[str] = []
    connect: list[str] = []
    config_file: str | None = Field(default=None, description="a Zenoh JSON5 file applied first")
    multicast_scouting: bool = False
    gossip: bool = True
    lease_s: float | None = Field(default=None, gt=0.0, le=3600.0, description="transport/link/tx/lease")
    shared_memory: bool = False
    multilink: bool = False
    connect_timeout_s: float = Field(default=10.0, ge=0.0, le=3600.0)
    reconnect_max_s: float = Field(default=1.0, ge=0.001, le=3600.0,
                                   description="connect/retry/period_max_ms: longest pause between tries to "
                                               "reach a lost connect endpoint (zenoh's default 4 s)")
    cfg: list[tuple[str, str]] = Field(default=[], description="KEY, JSON5 VALUE pairs applied last (--cfg)")
    tls_ca: str | None = Field(default=None, description="transport/link/tls/root_ca_certificate (mutual TLS on)")
    tls_cert: str | None = Field(default=None, description="this node's certificate (common name = its role)")
    tls_key: str | None = Field(default=None, description="its private key")
    access_control: dict[str, Any] | None = Field(default=None, description="zenoh access_control (default deny)")

    def to_zenoh(self) -> zenoh.Config:
        conf = zenoh.Config.from_file(self.config_file) if self.config_file else zenoh.Config()

        def put(path: str, value: Any) -> None:
            conf.insert_json5(path, json.dumps(value))

        put("mode", self.mode)
        if self.listen or self.tls_ca is not None:
            # with TLS, no listen endpoint means none: not zenoh's default plaintext tcp/[::]:0 of peers
            put("listen/endpoints", self.listen)
        if self.connect:
            endpoints: list[Any] = list(self.connect)
            if self.mode == "client" and self.multilink and len(endpoints) > 1:
                # a client opens only its first endpoint unless they are grouped
                endpoints = [{"strategy": "allOf", "locators": endpoints}]
            put("connect/endpoints", endpoints)
            # a restarted gateway (or a healed link) is found again within about this pause; zenoh's
            # default backs off to 4 s, which made the fleet reappear up to 4 s after a restart
            max_ms = int(self.reconnect_max_s * 1000)  # >= 1: a 0 ms pause would retry without pause
            put("connect/retry", {"period_init_ms": min(250, max_ms), "period_max_ms": max_ms,
                                  "period_increase_factor": 2})
        put("scouting/multicast/enabled", self.multicast_scouting)
        put("scouting/gossip/enabled", self.gossip)
        if self.lease_s is not None:
            put("transport/link/tx/lease", int(self.lease_s * 1000))
        put("transport/shared_memory/enabled", self.shared_memory)
        if self.multilink:
            put("transport/unicast/max_links", 2)
        if self.mode == "client":
            put("connect/timeout_ms", int(self.connect_timeout_s * 1000))
        if self.tls_ca is not None:
            # mutual TLS on tls/ links, both as listener and as dialler: every link presents the
            # node's certificate and checks the other's against the fleet CA; ACL subjects are common names
            put("transport/link/tls", {"root_ca_certificate": self.tls_ca, "enable_mtls": True,
                                       "listen_certificate": self.tls_cert, "listen_private_key": self.tls_key,
                                       "connect_certificate": self.tls_cert, "connect_private_key": self.tls_key})
        if self.access_control is not None:
            put("access_control", self.access_control)
        for key, value in self.cfg:
            try:
                conf.insert_json5(key, value)
            except zenoh.ZError as exc:
                raise ValueError(f"--cfg {key}:{value}: {exc}") from None
        return conf


def parse_cfg(text: Any) -> tuple[str, str]:
    """``KEY:VALUE`` of zenoh-python's examples' ``--cfg`` (VALUE is JSON5; an empty KEY is the root)."""
    if isinstance(text, (tuple, list)) and len(text) == 2:
        return str(text[0]), str(text[1])
    key, sep, value = str(text).partition(":")
    if not sep or not value.strip():
        raise ValueError(f"--cfg wants KEY:VALUE (VALUE in JSON5), got {text!r}")
    return key.strip().strip("/"), value


def multilink_endpoints(host: str, tcp_port: int, udp_port: int) -> list[str]:
    """The endpoint pair of the multilink setup: reliable on TCP, best-effort on UDP."""
    return [f"tcp/{host}:{tcp_port}?rel=1", f"udp/{host}:{udp_port}?rel=0"]


def endpoint_address(endpoint: str) -> str:
    """``host:port`` of a Zenoh endpoint such as ``udp/127.0.0.1:7448?rel=0``."""
    return endpoint.split("/", 1)[1].split("?", 1)[0].split("#", 1)[0]


#: one ``--cfg`` change: (KEY, JSON5 VALUE), written ``KEY:VALUE``
CfgChange = Annotated[tuple[str, str], BeforeValidator(parse_cfg), PlainSerializer(lambda kv: f"{kv[0]}:{kv[1]}")]
#: ``--mode``; a service's model redeclares the field with its own default (``mode: BusMode = "client"``)
BusMode = Annotated[Mode, Cli(short="-m", group="bus")]


#: ``--lease-s``; an edge redeclares the field with its own default (a short lease: a lost UAV is noticed)
LeaseS = Annotated[float | None, Cli(flag="--lease-s", metavar="S", group="bus"),
                   Field(gt=0.0, le=3600.0, description="link lease, seconds")]


class BusOptions(CliModel):
    """The session options every service takes: those of zenoh-python's examples, plus the fleet name and
    our session switches. A service's config model extends it (:mod:`protocol.cliconfig`)."""

    mode: BusMode = "peer"
    connect: Annotated[list[str], Cli(short="-e", metavar="ENDPOINT", group="bus")] = []
    listen: Annotated[list[str], Cli(short="-l", metavar="ENDPOINT", group="bus")] = []
    config: Annotated[str | None, Cli(short="-c", metavar="FILE", group="bus")] = Field(
        default=None, description="Zenoh JSON5 config applied first")
    cfg: Annotated[list[CfgChange], Cli(metavar="KEY:VALUE", group="bus")] = Field(
        default=[], description="a Zenoh config change applied last, VALUE in JSON5 (e.g. transport/link/tx/lease:3000)")
    fleet: Annotated[str, Cli(group="bus")] = Field(default=keys.DEFAULT_FLEET, description="fleet name (key space prefix)")
    lease: LeaseS = None
    multilink: Annotated[bool, Cli(group="bus")] = Field(default=False, description="reliable on TCP, best-effort on UDP")
    shm: Annotated[bool, Cli(group="bus")] = Field(default=False, description="enable shared-memory transport")
    scouting: Annotated[bool, Cli(group="bus")] = Field(default=False, description="enable multicast scouting")
    keys: Annotated[str | None, Cli(metavar="DIR", group="bus", exclusive="keys")] = Field(
        default=None, description="fleet key set (skynet keys init): this node's TLS certificate for tls/ endpoints, "
                                  "signing and trusted keys")

    @field_validator("fleet")
    @classmethod
    def _fleet(cls, v: str) -> str:
        keys.fleet_root(v)  # KeyError_ (a ValueError) for a name that is not one key chunk
        return v


def add_bus_args(parser: argparse.ArgumentParser, mode: Mode = "peer") -> None:
    """The options of :class:`BusOptions` on ``parser``, ``--mode`` defaulting to ``mode``."""
    add_options(parser, BusOptions, defaults={"mode": mode})


def config_from_args(args: BusOptions | argparse.Namespace, role: str | None = None, **overrides: Any) -> BusConfig:
    """The session config of a service's options; with ``--keys`` and its ``role``, mutual TLS."""
    opts = args if isinstance(args, BusOptions) else from_namespace(BusOptions, args)
    if opts.keys and role is not None:
        from .keyset import KeySet

        ks = KeySet(Path(opts.keys), role)
        overrides = {"tls_ca": str(ks.tls_ca), "tls_cert": str(ks.tls_cert), "tls_key": str(ks.tls_key), **overrides}
    values = dict(mode=opts.mode, connect=opts.connect, listen=opts.listen, config_file=opts.config, lease_s=opts.lease,
                  multilink=opts.multilink, shared_memory=opts.shm, multicast_scouting=opts.scouting, cfg=opts.cfg)
    values.update({k: v for k, v in overrides.items() if v is not None})
    return BusConfig(**values)


# ----------------------------------------------------------------------------- counters
#: distinct (key, kind) rejection rows a session keeps (see :meth:`Counters.reject`)
MAX_REJECT_KEYS = 512

@dataclass
class Counters:
    """Per-session traffic and rejection counters; updates from Zenoh's threads take a lock,
    publishers count on their own attributes (see :class:`Publisher`)."""

    sent: dict[str, list[int]] = field(default_factory=lambda: collections.defaultdict(lambda: [0, 0]))
    received: dict[str, list[int]] = field(default_factory=lambda: collections.defaultdict(lambda: [0, 0]))
    rejected: dict[tuple[str, str], int] = field(default_factory=lambda: collections.defaultdict(int))
    dropped: dict[str, int] = field(default_factory=lambda: collections.defaultdict(int))
    publishers: list[Publisher] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def add(self, table: dict[str, list[int]], key: str, nbytes: int) -> None:
        with self.lock:
            row = table[key]
            row[0] += 1
            row[1] += nbytes

    def reject(self, key: str, kind: str) -> bool:
        """Count a rejection; True the first time this (key, kind) is seen (log it once).

        At most :data:`MAX_REJECT_KEYS` distinct pairs are kept; the rest are counted under the key
        ``"(other)"``, so a flood of made-up keys cannot grow the table without bound."""
        with self.lock:
            if (key, kind) not in self.rejected and len(self.rejected) >= MAX_REJECT_KEYS:
                key = "(other)"
            first = (key, kind) not in self.rejected
            self.rejected[(key, kind)] += 1
            return first

    def snapshot(self) -> dict[str, Any]:
        with self.lock:
            sent = {k: list(v) for k, v in self.sent.items()}
            for p in self.publishers:
                row = sent.setdefault(p.link.name, [0, 0])
                row[0] += p.samples
                row[1] += p.bytes
            return {"sent": {k: {"samples": v[0], "bytes": v[1]} for k, v in sent.items()},
                    "received": {k: {"samples": v[0], "bytes": v[1]} for k, v in self.received.items()},
                    "rejected": {f"{k}|{kind}": n for (k, kind), n in self.rejected.items()},
                    "dropped": dict(self.dropped)}


# ----------------------------------------------------------------------------- results
@dataclass(frozen=True)
class Reply:
    """The outcome of :meth:`Bus.request`: ``ok`` only when an ok reply decoded as expected."""

    ok: bool
    message: Message | None = None
    error: str = ""
    elapsed_s: float = 0.0


class Rejected(Exception):
    """Raised by a :meth:`Bus.serve` handler to answer with ``reply_err`` and a reason."""

    def __init__(self, reason: str, code: str = "rejected"):
        super().__init__(reason)
        self.reason = reason
        self.code = code


class Publisher:
    """A declared publisher bound to one key and one link class."""

    def __init__(self, bus: Bus, key: str, link: LinkClass, cache: int | None = None):
        self.key = key
        self.link = link
        self.samples = 0
        self.bytes = 0
        if cache:
            # retransmission on request (RTP NACK-like): the last ``cache`` samples stay available to
            # subscribers that declare recovery, and a heartbeat lets them notice a lost last sample
            from zenoh import ext

            self._pub: Any = ext.declare_advanced_publisher(
                bus.session, key, **link.publisher_qos(), cache=ext.CacheConfig(cache),
                sample_miss_detection=ext.MissDetectionConfig(heartbeat=RECOVERY_HEARTBEAT_S, sporadic_heartbeat=None))
        else:
            self._pub = bus.session.declare_publisher(key, **link.publisher_qos())
        self._put = self._pub.put
        bus.counters.publishers.append(self)

    def put(self, msg: Message) -> int:
        return self.put_bytes(codec.encode(msg), encoding_of(msg))

    def put_bytes(self, data: bytes, encoding: zenoh.Encoding | None = None, attachment: bytes | None = None) -> int:
        """Put ``data``; ``attachment``: Zenoh's per-sample attachment (a replay's mark, services.recording.replay)."""
        self._put(data, encoding=encoding, attachment=attachment)
        n = len(data)
        self.samples += 1
        self.bytes += n
        return n

    def matching(self) -> bool | None:
        """Whether a subscriber matches; None for a recovery-cache publisher (Zenoh does not say)."""
        status = getattr(self._pub, "matching_status", None)
        return None if status is None else bool(status.matching)

    def undeclare(self) -> None:
        self._pub.undeclare()


_ENCODINGS: dict[str, zenoh.Encoding] = {}


def encoding_of(msg: Message) -> zenoh.Encoding:
    """The Zenoh encoding of a message's samples (:func:`protocol.codec.encoding_name`), made once per type."""
    enc = _ENCODINGS.get(msg.TYPE)
    if enc is None:
        enc = _ENCODINGS[msg.TYPE] = zenoh.Encoding(codec.encoding_name(msg.TYPE))
    return enc


def _reply_err(query: zenoh.Query, error: ErrorReply) -> None:
    query.reply_err(codec.encode(error), encoding=encoding_of(error))


# ----------------------------------------------------------------------------- the bus
class Bus:
    """One Zenoh session with typed helpers. Use as a context manager or call :meth:`close`."""

    def __init__(self, config: BusConfig | None = None, fleet: str = keys.DEFAULT_FLEET, name: str = "node"):
        self.config = config or BusConfig()
        self.fleet = fleet
        self.name = name
        self.counters = Counters()
        self.session = zenoh.open(self.config.to_zenoh())
        self._entities: list[Any] = []
        self._rings: list[Ring] = []
        self._closed = False
        self._close_lock = threading.Lock()

    # -- context management
    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        with self._close_lock:
            if self._closed:
                return
            self._closed = True
        for ring in self._rings:
            ring.close()
        try:
            self.session.close()
        except Exception:  # closing twice or after a transport error is harmless
            log.debug("session close", exc_info=True)

    @property
    def closed(self) -> bool:
        return self._closed

    # -- publish
    def publisher(self, key: str, link: LinkClass, cache: int | None = None) -> Publisher:
        """A publisher with the link class's QoS; ``cache=N`` keeps the last N samples for recovery."""
        return Publisher(self, key, link, cache)

    # -- subscribe
    def _decode_or_count(self, key: str, data: bytes, expect: Any) -> Message | None:
        try:
            msg: Message = codec.decode(data, expect)
            return msg
        except codec.CodecError as exc:
            if self.counters.reject(key, exc.kind):
                log.warning("%s: rejected sample on %s (%s); further ones of this kind are only counted",
                            self.name, key, exc)
            return None

    def subscribe(self, key: str, callback: Callable[[Message, zenoh.Sample], None],
                  expect: type[Message] | tuple[type[Message], ...] | None = None, link: LinkClass | None = None,
                  ring: int | None = None, budget: Budget | None = None) -> Any:
        """Subscribe with decoding; ``ring=N`` hands samples to a worker through a drop-oldest ring;
        ``budget`` drops (and counts) what a source sends beyond its rate or size (:mod:`protocol.budget`)."""
        counters = self.counters
        cls_name = link.name if link else "any"

        def handle(sample: zenoh.Sample) -> None:
            payload = sample.payload
            nbytes = len(payload)
            counters.add(counters.received, cls_name, nbytes)
            source = str(sample.key_expr)
            if budget is None:
                msg = self._decode_or_count(source, payload.to_bytes(), expect)
                if msg is not None:
                    callback(msg, sample)
                return
            now = time.monotonic()
            if not self._within_budget(budget, source, nbytes, now):
                return  # too large, or a source flooding garbage: not even copied or decoded
            msg = self._decode_or_count(source, payload.to_bytes(), expect)
            if msg is None:  # garbage takes from the source's garbage bucket (protocol.budget)
                with counters.lock:
                    budget.charge_garbage(source, now)
            # the rate is charged only to well-formed samples, so that garbage on a key does not use up the
            # budget of the source that really writes it
            elif self._within_budget(budget, source, None, now):
                callback(msg, sample)

        return self.subscribe_raw(key, handle, ring=ring)

    def _within_budget(self, budget: Budget, source: str, nbytes: int | None, now: float) -> bool:
        """With ``nbytes``: what ``budget`` can tell before decoding (size, a used-up rate, a source flooding
        garbage); without: the rate check of a well-formed sample. A refusal is counted (logged once)."""
        with self.counters.lock:
            if nbytes is not None:
                reason = budget.admit_undecoded(source, nbytes, now)
            else:
                reason = budget.admit_rate(source, now)
        if reason is None:
            return True
        if self.counters.reject(source, reason):
            log.warning("%s: %s over its budget (%s); further ones are only counted", self.name, source, reason)
        return False

    def subscribe_raw(self, key: str, callback: Callable[[zenoh.Sample], None], ring: int | None = None,
                      recover: bool = False) -> Any:
        """Subscribe to raw samples (e.g. RTP frames); the callback must not raise for bad input.

        ``recover=True`` asks publishers that keep a cache (``publisher(..., cache=N)``) to
        retransmit samples lost on the way; samples are then delivered in order, a gap holding
        later ones back until it is recovered. What cannot be recovered is counted as
        ``missed`` in :attr:`counters`.
        """
        target: Callable[[zenoh.Sample], object] = callback
        if ring is not None:
            r = Ring(ring, callback, name=f"ring:{key}")
            self._rings.append(r)
            target = r.push

        def guarded(sample: zenoh.Sample) -> None:
            if self._closed:
                return
            try:
                target(sample)
            except Exception:
                if self.counters.reject(str(sample.key_expr), "handler-error"):
                    log.exception("%s: subscriber on %s failed", self.name, key)

        if recover:
            from zenoh import ext

            sub: Any = ext.declare_advanced_subscriber(self.session, key, guarded,
                                                  recovery=ext.RecoveryConfig(heartbeat=True, periodic_queries=None))

            def on_miss(miss: Any) -> None:
                with self.counters.lock:
                    self.counters.dropped[f"missed:{key}"] += int(miss.nb)

            self._entities.append(sub.sample_miss_listener(on_miss))
        else:
            sub = self.session.declare_subscriber(key, guarded)
        self._entities.append(sub)
        return sub

    def ring_stats(self) -> dict[str, dict[str, int]]:
        return {r.name: {"dropped": r.dropped, "processed": r.processed, "queued": len(r)} for r in self._rings}

    # -- request / reply
    def request(self, key: str, msg: Message, expect: type[Message] | tuple[type[Message], ...] | None = None,
                timeout: float = 2.0, link: LinkClass = COMMAND) -> Reply:
        """Send a query; acknowledged (``ok``) only by an ok reply that decodes as ``expect``.

        Nobody listening, a crashed queryable, a timeout or an error reply all give ``ok=False``
        with the reason.
        """
        t0 = time.perf_counter()
        payload = codec.encode(msg)
        self.counters.add(self.counters.sent, link.name, len(payload))
        try:
            replies = self.session.get(key, payload=payload, encoding=encoding_of(msg), timeout=timeout,
                                       **link.request_qos())
            for reply in replies:
                return self._one_reply(key, reply, expect, t0)  # the consolidated answer
        except zenoh.ZError as exc:
            return Reply(False, None, f"query failed: {exc}", time.perf_counter() - t0)
        return Reply(False, None, f"no reply from {key} (nobody listening)", time.perf_counter() - t0)

    def request_all(self, key: str, msg: Message, expect: type[Message] | tuple[type[Message], ...] | None = None,
                    timeout: float = 2.0, settle_s: float = 10.0, link: LinkClass = COMMAND, max_replies: int = 16,
                    settles: Callable[[Message], bool] | None = None) -> list[Reply]:
        """Send a query to *every* matching queryable and gather every answer, unconsolidated (not Zenoh's
        consolidated "latest" one: several sessions may answer the same key). Gathers until every answerer
        finished, ``timeout`` passed, or ``settle_s`` after the first ok answer that ``settles`` accepts (any ok
        answer without it; so a garbage answer does not start the clock), a later answer is not waited for; at most
        ``max_replies`` (the rest counted as rejected). Each answer is a :class:`Reply` as :meth:`request` makes
        them; an empty list means nobody answered."""
        t0 = time.perf_counter()
        payload = codec.encode(msg)
        self.counters.add(self.counters.sent, link.name, len(payload))
        inbox: queue.Queue[Any] = queue.Queue(maxsize=max_replies + 1)
        done = object()

        def on_reply(reply: zenoh.Reply) -> None:
            try:
                inbox.put_nowait(reply)
            except queue.Full:
                self.counters.reject(key, "too-many-replies")

        def on_end() -> None:
            with contextlib.suppress(queue.Full):
                inbox.put_nowait(done)

        try:
            self.session.get(key, payload=payload, encoding=encoding_of(msg), timeout=timeout,
                             target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE,
                             handler=zenoh.handlers.Callback(on_reply, on_end), **link.request_qos())
        except zenoh.ZError as exc:
            return [Reply(False, None, f"query failed: {exc}", time.perf_counter() - t0)]
        out: list[Reply] = []
        deadline = time.monotonic() + timeout + 1.0  # the query's own timeout ends the stream first
        while len(out) < max_replies:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            try:
                reply = inbox.get(timeout=left)
            except queue.Empty:
                break
            if reply is done:
                break
            out.append(self._one_reply(key, reply, expect, t0))
            answer = out[-1].message
            if out[-1].ok and (settles is None or (answer is not None and settles(answer))):
                deadline = min(deadline, time.monotonic() + settle_s)
        return out

    def _one_reply(self, key: str, reply: zenoh.Reply, expect: type[Message] | tuple[type[Message], ...] | None,
                   t0: float) -> Reply:
        """One Zenoh reply as a :class:`Reply` (decoded as ``expect``, or the error it carries)."""
        if reply.ok is not None:
            try:
                answer = codec.decode(reply.ok.payload.to_bytes(), expect)
            except codec.CodecError as exc:
                self.counters.reject(key, exc.kind)
                return Reply(False, None, f"bad reply: {exc}", time.perf_counter() - t0)
            return Reply(True, answer, "", time.perf_counter() - t0)
        err = reply.err
        text = err.payload.to_bytes() if err is not None else b""
        try:
            reason = codec.decode(text, ErrorReply).reason
        except codec.CodecError:
            reason = text.decode("utf-8", "replace")[:500] or "error reply"
        return Reply(False, None, reason, time.perf_counter() - t0)

    def serve(self, key: str, handler: Callable[[Message], Message],
              expect: type[Message] | tuple[type[Message], ...] | None = None, ring: int | None = None) -> Any:
        """Declare a queryable: decode, call ``handler``, reply ok with its answer.

        Decoding failures and :class:`Rejected` answer with ``reply_err`` and an
        :class:`ErrorReply`; any other handler exception answers ``internal`` (and is logged),
        so a query never hangs until its timeout because of a bug.
        """

        def answer(query: zenoh.Query) -> None:
            qkey = str(query.key_expr)
            try:
                data = query.payload.to_bytes() if query.payload is not None else b""
                self.counters.add(self.counters.received, COMMAND.name, len(data))
                try:
                    msg = codec.decode(data, expect)
                except codec.CodecError as exc:
                    self.counters.reject(qkey, exc.kind)
                    _reply_err(query, ErrorReply(code=exc.kind, reason=str(exc)))
                    return
                try:
                    result = handler(msg)
                except Rejected as exc:
                    _reply_err(query, ErrorReply(code=exc.code, reason=exc.reason))
                    return
                except Exception as exc:
                    log.exception("%s: handler on %s failed", self.name, qkey)
                    _reply_err(query, ErrorReply(code="internal", reason=f"{type(exc).__name__}: {exc}"[:500]))
                    return
                out = codec.encode(result)
                self.counters.add(self.counters.sent, COMMAND.name, len(out))
                query.reply(query.key_expr, out, encoding=encoding_of(result))
            finally:
                query.drop()

        if ring is not None:
            r = Ring(ring, answer, name=f"ring:{key}")
            self._rings.append(r)
            q = self.session.declare_queryable(key, r.push)
        else:
            q = self.session.declare_queryable(key, answer)
        self._entities.append(q)
        return q

    # -- liveliness
    def token(self, key: str) -> Any:
        tok = self.session.liveliness().declare_token(key)
        self._entities.append(tok)
        return tok

    def watch_alive(self, key: str, on_change: Callable[[str, bool], None]) -> Any:
        """``on_change(key, alive)`` for every token matching ``key``, current ones first."""

        def handle(sample: zenoh.Sample) -> None:
            if self._closed:
                return
            on_change(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

        sub = self.session.liveliness().declare_subscriber(key, handle, history=True)
        self._entities.append(sub)
        return sub

    def alive(self, key: str, timeout: float = 1.0) -> list[str]:
        """Keys of the liveliness tokens currently matching ``key``."""
        found = []
        for reply in self.session.liveliness().get(key, timeout=timeout):
            if reply.ok is not None:
                found.append(str(reply.ok.key_expr))
        return found

    # -- introspection
    def links(self) -> list[Any]:
        return list(self.session.info.links())

    def peers(self) -> list[str]:
        return [str(z) for z in self.session.info.peers_zid()]

    def routers(self) -> list[str]:
        return [str(z) for z in self.session.info.routers_zid()]


# ----------------------------------------------------------------------------- process helpers
def setup_logging(name: str, level: str = "INFO") -> logging.Logger:
    """The process's log on stderr, one line a record, with text from other nodes escaped
    (:class:`protocol.textsafe.SafeFormatter`); zenoh's own lines (``RUST_LOG``, default errors) without ANSI
    colours unless stdout, where zenoh writes them, is a terminal (``NO_COLOR``, honoured by its tracing subscriber)."""
    from .textsafe import SafeFormatter

    root = logging.getLogger()
    before = set(root.handlers)
    fmt, datefmt = f"%(asctime)s {name} %(levelname)s %(message)s", "%H:%M:%S"
    logging.basicConfig(level=getattr(logging, level.upper(), logging.INFO), format=fmt, datefmt=datefmt)
    for h in root.handlers:
        if h not in before:
            h.setFormatter(SafeFormatter(fmt, datefmt))
    if not sys.stdout.isatty():  # zenoh writes on stdout: to a file or a pipe (services.log) without colours
        os.environ.setdefault("NO_COLOR", "1")
    zenoh.init_log_from_env_or("error")
    return logging.getLogger(f"skynet.{name}")
