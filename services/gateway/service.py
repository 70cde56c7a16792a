"""The gateway router relay: SkyNet (UAV peers) <-> the Internet (RCU and GCS clients).

Design notes: docs/bus.md (services/gateway/service.py).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import zenoh

from protocol import acl, keys
from protocol.bus import (
    Bus,
    BusConfig,
    config_from_args,
    endpoint_address,
    multilink_endpoints,
    setup_logging,
    stop_event_on_signals,
)
from protocol.cliconfig import add_options, from_namespace
from protocol.heap import release_freed_memory
from protocol.links import LINK_CLASSES, TELEMETRY, class_of_topic
from protocol.messages import ClassCounters, LinkStats
from protocol.readiness import notify_ready

from . import ingress
from .config import GatewayConfig


class RouterConfig(BusConfig):
    """The router's session config: a :class:`BusConfig` plus ingress downsampling."""

    #: downsampling items added to those of the config file and ``--cfg`` (:mod:`services.gateway.ingress`)
    downsampling: list[dict[str, Any]] = []

    def to_zenoh(self) -> zenoh.Config:
        conf = super().to_zenoh()
        if self.downsampling:
            current = json.loads(conf.get_json("downsampling") or "[]")
            conf.insert_json5("downsampling", json.dumps(current + self.downsampling))
        return conf


class TrafficMeter:
    """Samples and bytes per link class for the fleet's keys (pure; fed by the subscriber)."""

    def __init__(self) -> None:
        self.samples: Counter[str] = Counter()
        self.bytes: Counter[str] = Counter()
        self.unknown = 0

    def observe(self, key: str, nbytes: int) -> None:
        try:
            info = keys.parse(key)
        except keys.KeyError_:
            self.unknown += 1
            return
        name = class_of_topic(info.topic).name
        self.samples[name] += 1
        self.bytes[name] += nbytes

    def classes(self) -> dict[str, ClassCounters]:
        return {n: ClassCounters(samples=self.samples[n], bytes=self.bytes[n]) for n in LINK_CLASSES}


def session_counts(bus: Bus) -> dict[str, int]:
    counts: Counter[str] = Counter()
    for tr in bus.session.info.transports():
        counts[str(tr.whatami).split(".")[-1].lower()] += 1
    return dict(counts)


def build_parser() -> argparse.ArgumentParser:
    """``skynet gateway``'s command line: the options of :class:`GatewayConfig`."""
    return add_options(argparse.ArgumentParser(prog="skynet gateway", description=__doc__.split("\n\n")[0]),
                       GatewayConfig)


def guarded(listen: list[str], log=None) -> tuple[list[str], list[Any]]:
    """Each ``tls/HOST:PORT`` listener moved to a loopback port behind an accept guard on HOST:PORT
    (:mod:`services.gateway.guard`); the listeners zenoh opens instead, and the started guards."""
    import socket

    from services.orchestration.process import free_port

    from .guard import Guard

    out, guards = [], []
    for e in listen:
        host, _, port = endpoint_address(e).rpartition(":") if e.startswith("tls/") else ("", "", "")
        if not host or not port.isdigit() or port == "0":  # not a TLS listener on a fixed port: zenoh judges it
            out.append(e)
            continue
        inner = free_port(socket.SOCK_STREAM)
        while inner == int(port):  # the outer port is not bound yet: the kernel may offer it again
            inner = free_port(socket.SOCK_STREAM)
        guards.append(Guard((host.strip("[]"), int(port)), ("127.0.0.1", inner)).start())
        out.append(e.replace(f"{host}:{port}", f"127.0.0.1:{inner}", 1))
        if log:
            log.info("accept guard on %s:%s -> zenoh's TLS listener on 127.0.0.1:%d", host, port, inner)
    return out, guards


def main(argv: list[str] | None = None) -> int:
    """``skynet gateway``: parse the command line, then :func:`run` the router."""
    parser = build_parser()
    return run(from_namespace(GatewayConfig, parser.parse_args(argv), parser))


def run(args: GatewayConfig) -> int:
    """The gateway router relay from its configuration, until SIGINT/SIGTERM."""
    log = setup_logging(f"gateway-{args.id}")
    listen = list(args.listen)
    multilink = args.multilink
    if args.port is not None:
        listen += multilink_endpoints(args.host, args.port, args.port + 1)
        multilink = True
    if not listen and not args.config:
        listen = multilink_endpoints(args.host, 7447, 7448)
        multilink = True
    guards = []
    if args.accept_guard:
        listen, guards = guarded(listen, log)
    base = config_from_args(args, role="gateway", listen=listen, multilink=multilink)
    thin = ingress.state_ingress(args.fleet, args.state_ingress_hz) if args.state_ingress_hz else []
    config = RouterConfig(**dict(base), downsampling=thin)
    names = admitted(args.keys)
    if args.keys:
        # mutual TLS: ACL by certificate common name on every listener; a tcp/ or udp/ listener admits no
        # certificate, so what arrives there matches no subject and is denied everything (default deny)
        plain = [e for e in listen if not e.startswith("tls/")]
        if plain:
            log.warning("listeners without TLS (%s): no certificate there, so denied everything", ", ".join(plain))
    stop = stop_event_on_signals()
    relay = Relay(args, listen, guards, stop)
    try:
        while names is not None and not stop.is_set():
            acl_config = config
            if args.keys:
                acl_config = config.model_copy(update={"access_control": acl.cert_access_control(args.fleet, names)})
                log.info("ACL by certificate common name for %s", ", ".join(names))
            try:
                names = relay.run(acl_config, names)
            except zenoh.ZError as exc:  # a reopen that cannot bind (the old listener not yet released): retry
                if not relay.opened:
                    raise
                log.warning("router did not reopen (%s); retrying in %s s", exc, args.period)
                stop.wait(args.period)
                with contextlib.suppress(OSError, ValueError):  # a key set fixed meanwhile is the one applied
                    names = admitted(args.keys)
    finally:
        for g in guards:
            g.stop()
    return 0


def admitted(folder: str | None) -> list[str]:
    """The certificate common names the key set admits now (none without a key set)."""
    from protocol.keyset import KeySet

    return KeySet(folder, "gateway").admitted() if folder else []


@dataclass
class Relay:
    """The router's session, reopened when the key set's admitted names change (so a revoked one's sessions end)."""

    args: GatewayConfig
    listen: list[str]
    guards: list[Any]
    stop: threading.Event
    meter: TrafficMeter = field(default_factory=TrafficMeter)
    t0: float = field(default_factory=time.time)
    opened: int = 0
    #: rejections counted by the routers closed so far (a reopen keeps the totals)
    carried: Counter[str] = field(default_factory=Counter)

    def run(self, config: RouterConfig, names: list[str]) -> list[str] | None:
        """The router until ``stop`` (None) or until the admitted names change (the names admitted now)."""
        with Bus(config, fleet=self.args.fleet, name="gateway") as bus:
            try:
                now = self._serve(bus, names)
            finally:
                self.carried.update(bus.counters.snapshot()["rejected"])
        release_freed_memory()  # what the closed router held goes back to the system
        return now

    def _serve(self, bus: Bus, names: list[str]) -> list[str] | None:
        from protocol.keyset import AdmissionWatch

        args, meter, log = self.args, self.meter, logging.getLogger(f"gateway-{self.args.id}")
        self.opened += 1
        log.info("router up, listening on %s", ", ".join(self.listen) or "(config file)")
        if self.opened == 1:
            notify_ready("gateway", args.id)
        for key in keys.metered(args.fleet):  # not the previews: a meter would make every camera render them
            bus.subscribe_raw(key, lambda s: meter.observe(str(s.key_expr), len(s.payload)))
        pub = bus.publisher(keys.gateway_stats(args.fleet, args.id), TELEMETRY)
        sessions = 0
        watch = AdmissionWatch(lambda: admitted(args.keys), names, min_interval_s=0.0)
        while not self.stop.wait(args.period):
            counts = session_counts(bus)
            if sum(counts.values()) < sessions:
                release_freed_memory()  # what a departed session's declarations held goes back to the system
            sessions = sum(counts.values())
            snap = bus.counters.snapshot()
            rejected = {"unknown-key": meter.unknown, **(self.carried + Counter(snap["rejected"])),
                        **{f"guard-{k}": v for g in self.guards for k, v in dict(g.counts).items() if k != "pass"}}
            pub.put(LinkStats(source=f"gateway/{args.id}", stamp=time.time(), uptime_s=time.time() - self.t0,
                              sessions=counts, classes=meter.classes(), rejected=rejected))
            now = watch()
            if now is not None:
                gone, new = sorted(set(names) - set(now)), sorted(set(now) - set(names))
                log.warning("key set changed (revoked: %s; admitted: %s); reopening the router so that its "
                            "sessions end", ", ".join(gone) or "none", ", ".join(new) or "none")
                return now
        log.info("shutting down")
        return None


if __name__ == "__main__":
    raise SystemExit(main())
