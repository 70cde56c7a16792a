"""The gateway router relay: SkyNet (UAV peers) <-> the Internet (RCU and GCS clients).

A Zenoh *router* session (DESIGN.md, "The network") listening on TCP and UDP with the
multilink setup, so reliable traffic rides TCP and best-effort traffic UDP. Once a second it
publishes :class:`~protocol.messages.LinkStats` on ``skynet/<fleet>/gateway/<id>/stats``:
connected sessions by kind and samples/bytes per link class seen on the fleet's keys.

    skynet gateway --listen tcp/0.0.0.0:7447?rel=1 --listen udp/0.0.0.0:7448?rel=0
    skynet gateway --port 7447           # the same, TCP on 7447 and UDP on 7448

Authentication and access control (off by default): ``--users FILE`` (lines ``user:password``)
makes every node that connects present one of those users (``--user``, and ``--password`` or
``SKYNET_PASSWORD``); ``--acl`` adds the role rules of :mod:`protocol.acl` (default deny),
roles from ``--roles FILE`` (lines ``user:role``) or from the user names (``uav1``..``uav255``,
``gcs``, ``planner``, ``detector``, ``gateway``).
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from typing import Any

import zenoh

from protocol import acl, keys
from protocol.bus import (
    Bus,
    BusConfig,
    add_bus_args,
    config_from_args,
    endpoint_address,
    multilink_endpoints,
    setup_logging,
    stop_event_on_signals,
)
from protocol.checks import rate_arg
from protocol.links import LINK_CLASSES, TELEMETRY, class_of_topic
from protocol.messages import ClassCounters, LinkStats

from . import ingress


class GatewayConfig(BusConfig):
    """The router's session config: a :class:`BusConfig` plus the users dictionary and the ACL."""

    dictionary_file: str | None = None
    access_control: dict[str, Any] | None = None
    #: downsampling items added to those of the config file and ``--cfg`` (:mod:`services.gateway.ingress`)
    downsampling: list[dict[str, Any]] = []

    def to_zenoh(self) -> zenoh.Config:
        conf = super().to_zenoh()
        if self.downsampling:
            current = json.loads(conf.get_json("downsampling") or "[]")
            conf.insert_json5("downsampling", json.dumps(current + self.downsampling))
        if self.dictionary_file:
            conf.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(self.dictionary_file))
        if self.access_control is not None:
            conf.insert_json5("access_control", json.dumps(self.access_control))
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
    parser = argparse.ArgumentParser(prog="skynet gateway", description=__doc__.split("\n\n")[0])
    add_bus_args(parser, mode="router")
    parser.add_argument("--id", default="1", help="gateway id (key space)")
    parser.add_argument("--host", default="127.0.0.1", help="listen host when --port is used")
    parser.add_argument("--port", type=int, default=None, help="TCP port; UDP uses port+1 (multilink)")
    parser.add_argument("--period", type=float, default=1.0, help="statistics period, s")
    parser.add_argument("--state-ingress-hz", type=rate_arg, default=ingress.STATE_INGRESS_HZ, metavar="HZ",
                        help="states a connected session may send per UAV key through the gateway, at most one "
                             "per 1/HZ (Zenoh ingress downsampling per face; services/gateway/ingress.py); 0: off")
    parser.add_argument("--accept-guard", action="store_true",
                        help="accept tls/ connections in a guard that passes on only those starting a TLS handshake "
                             "(services/gateway/guard.py): connect-and-close or silent floods never reach zenoh")
    sec = parser.add_argument_group("authentication and access control")
    sec.add_argument("--users", default=None, metavar="FILE",
                     help="user/password authentication: every node must present a user of FILE (lines user:password)")
    sec.add_argument("--acl", action="store_true", help="enforce the role rules (needs --users); default deny")
    sec.add_argument("--roles", default=None, metavar="FILE",
                     help="lines user:role (uavN, gcs, planner, detector, gateway); else the role comes from the name")
    return parser


def security_options(args: argparse.Namespace, log=None) -> dict[str, Any]:
    """``dictionary_file`` and ``access_control`` for :class:`GatewayConfig` from the options.

    Raises ValueError for a malformed users or roles file, or ``--acl``/``--roles`` without
    ``--users`` (the rules name users).
    """
    if not args.users:
        if args.acl or args.roles:
            raise ValueError("--acl and --roles need --users (the rules name authenticated users)")
        return {}
    users = acl.read_users(args.users)
    out: dict[str, Any] = {"dictionary_file": str(args.users)}
    if log:
        log.info("authentication on: %d users", len(users))
    if args.roles and not args.acl:
        raise ValueError("--roles needs --acl")
    if args.acl:
        roles = acl.read_roles(args.roles) if args.roles else {}
        unknown = sorted(set(roles) - set(users))
        if unknown:
            raise ValueError(f"roles file names users that are not in the users file: {', '.join(unknown)}")
        principals, unassigned = acl.assign_roles(users, roles)
        out["access_control"] = acl.access_control(args.fleet, principals)
        if log:
            log.info("access control on (default deny): %s", ", ".join(f"{p.user}={p.subject}" for p in principals))
            if unassigned:
                log.warning("users without a role (denied everything): %s", ", ".join(unassigned))
    return out


def guarded(listen: list[str], log=None) -> tuple[list[str], list[Any]]:
    """Each ``tls/HOST:PORT`` listener moved to a loopback port behind an accept guard on HOST:PORT
    (:mod:`services.gateway.guard`); the listeners zenoh opens instead, and the started guards."""
    import socket

    from services.orchestration.process import free_port

    from .guard import Guard

    out, guards = [], []
    for e in listen:
        host, _, port = endpoint_address(e).rpartition(":")
        if not e.startswith("tls/") or port == "0":
            out.append(e)
            continue
        inner = free_port(socket.SOCK_STREAM)
        guards.append(Guard((host.strip("[]"), int(port)), ("127.0.0.1", inner)).start())
        out.append(e.replace(f"{host}:{port}", f"127.0.0.1:{inner}", 1))
        if log:
            log.info("accept guard on %s:%s -> zenoh's TLS listener on 127.0.0.1:%d", host, port, inner)
    return out, guards


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
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
    config = GatewayConfig(**{**dict(base), **security_options(args, log)}, downsampling=thin)
    if args.keys and config.access_control is None:
        # mutual TLS: ACL by certificate common name on every listener; a tcp/ or udp/ listener admits no
        # certificate, so what arrives there matches no subject and is denied everything (default deny)
        from protocol.keyset import KeySet
        names = KeySet(args.keys, "gateway").admitted()
        config = config.model_copy(update={"access_control": acl.cert_access_control(args.fleet, names)})
        log.info("ACL by certificate common name for %s", ", ".join(names))
        plain = [e for e in listen if not e.startswith("tls/")]
        if plain:
            log.warning("listeners without TLS (%s): no certificate there, so denied everything", ", ".join(plain))
    stop = stop_event_on_signals()
    meter = TrafficMeter()
    with Bus(config, fleet=args.fleet, name="gateway") as bus:
        log.info("router up, listening on %s", ", ".join(listen) or "(config file)")
        for key in keys.metered(args.fleet):  # not the previews: a meter would make every camera render them
            bus.subscribe_raw(key, lambda s: meter.observe(str(s.key_expr), len(s.payload)))
        stats_key = keys.gateway_stats(args.fleet, args.id)
        pub = bus.publisher(stats_key, TELEMETRY)
        t0 = time.time()
        while not stop.wait(args.period):
            snap = bus.counters.snapshot()
            rejected = {"unknown-key": meter.unknown, **{k: v for k, v in snap["rejected"].items()},
                        **{f"guard-{k}": v for g in guards for k, v in g.counts.items() if k != "pass"}}
            pub.put(LinkStats(source=f"gateway/{args.id}", stamp=time.time(), uptime_s=time.time() - t0,
                              sessions=session_counts(bus), classes=meter.classes(), rejected=rejected))
        log.info("shutting down")
    for g in guards:
        g.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
