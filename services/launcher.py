"""The embedded default: the whole network on one machine, as separate processes on loopback.

``skynet up`` starts the gateway, N edges (SkyNet peers), the planner and the detector on free
loopback ports, prefixes each service's log lines with its name, and stops everything cleanly
on Ctrl-C (SIGINT to every child so sessions close, then SIGTERM/SIGKILL for stragglers).

``skynet mission`` does the same, then runs the ground station's mission on the scenario in
this process (a Zenoh client, with the live progress display) and writes the report; its exit
status is the mission's.

Impairment experiments: ``--impair uav2="delay 50ms jitter 10ms loss 2%"`` puts user-space
netem proxies (:mod:`services.netem`, TCP and UDP) between that node and the gateway; names
are ``uavN``, ``planner``, ``detector`` and ``gcs``. Shared memory stays off so that nothing
bypasses them. (Edges also mesh directly with each other; those SkyNet links are not proxied.)

``--secure`` turns on the gateway's authentication and access control: random passwords for
``gcs``, ``planner``, ``detector`` and ``uav1..N`` in a private temporary folder (removed at the
end), the gateway started with ``--users`` and ``--acl``, each service with ``--user`` and its
password in ``SKYNET_PASSWORD``, the edges with the UAVs' dictionary (``--config``, see
:mod:`services.gateway.credentials`) so that they accept each other's links.
"""

from __future__ import annotations

import argparse
import logging
import math
import shutil
import sys
import tempfile
import time
from pathlib import Path

from protocol.bus import (PASSWORD_ENV, Bus, BusConfig, endpoint_address, multilink_endpoints, setup_logging,
                          stop_event_on_signals)

from .process import ProcessGroup, free_port_pair

HOST = "127.0.0.1"


def parse_impair(items: list[str]) -> dict[str, str]:
    out = {}
    for item in items:
        name, sep, spec = item.partition("=")
        if not sep or not spec.strip():
            raise argparse.ArgumentTypeError(f"--impair wants NAME=SPEC, got {item!r}")
        out[name.strip()] = spec.strip()
    return out


class Network:
    """The processes of one run and the endpoints each node connects to."""

    def __init__(self, args: argparse.Namespace, echo=sys.stdout, log_dir: Path | None = None):
        self.args = args
        self.group = ProcessGroup(echo=echo)
        self.log_dir = log_dir
        self.proxies: list = []
        tcp, udp = free_port_pair()
        self.gateway_endpoints = multilink_endpoints(HOST, tcp, udp)
        self.impair = parse_impair(args.impair or [])
        self.epoch = time.time() + 3.0
        self.creds = None
        if getattr(args, "secure", False):
            from services.gateway.credentials import generate

            users = ["gcs", "planner", "detector", *[f"uav{i}" for i in range(1, args.uavs + 1)]]
            self.creds = generate(tempfile.mkdtemp(prefix="skynet-creds-"), users)

    def endpoints_for(self, name: str) -> list[str]:
        """Where ``name`` connects: the gateway, or impairment proxies in front of it."""
        spec = self.impair.get(name)
        if spec is None:
            return self.gateway_endpoints
        from services.netem.proxy import TcpProxy, UdpProxy

        tcp_target, udp_target = (endpoint_address(e) for e in self.gateway_endpoints)
        tp = TcpProxy((HOST, 0), tcp_target, spec, seed=self.args.seed).start()
        up = UdpProxy((HOST, 0), udp_target, spec, seed=self.args.seed + 1).start()
        self.proxies += [(name, tp), (name, up)]
        return multilink_endpoints(HOST, tp.port, up.port)

    def bus_args(self, name: str, mode: str) -> list[str]:
        args = ["--mode", mode, "--fleet", self.args.fleet, "--multilink"]
        for e in self.endpoints_for(name):
            args += ["--connect", e]
        if self.creds is not None:
            args += ["--user", name]
        return args

    def start_service(self, name: str, args: list[str]):
        """Start a service; with --secure its password goes in its environment, not on its command line."""
        if self.creds is not None:
            self.group.env[PASSWORD_ENV] = self.creds.passwords[name]
        try:
            return self.group.start(name, args)
        finally:
            self.group.env.pop(PASSWORD_ENV, None)

    def gcs_config(self) -> BusConfig:
        """The in-process ground station's session."""
        creds = {} if self.creds is None else {"user": "gcs", "password": self.creds.passwords["gcs"]}
        return BusConfig(mode="client", connect=self.endpoints_for("gcs"), multilink=True, **creds)

    def homes(self, n: int) -> list[tuple[float, float, float]]:
        """Launch points: the formation slots around the start, on the ground (P9)."""
        from edge.formation import offsets_for, rotation_of
        from services.planner.scenario import load_scenario_document

        sc = load_scenario_document(self.args.scenario)
        start, goal = sc["start"], sc["goal"]
        yaw = math.atan2(goal[1] - start[1], goal[0] - start[0])
        R = rotation_of(0.0, 0.0, yaw)
        ground = sc["box"]["lo"][2]
        out = []
        for off in offsets_for(n):
            p = (R @ off)[:2]
            out.append((round(start[0] + p[0], 3), round(start[1] + p[1], 3), ground))
        return out

    def start(self) -> None:
        a = self.args
        secure = [] if self.creds is None else ["--users", str(self.creds.users_file), "--acl"]
        gw = self.group.start("gateway", ["gateway", "--fleet", a.fleet, "--multilink", *secure,
                                          *[x for e in self.gateway_endpoints for x in ("--listen", e)]])
        if not gw.wait_for("router up", 30):
            raise RuntimeError("the gateway did not start:\n" + "\n".join(gw.lines[-20:]))
        scenario = ["--scenario", a.scenario] if a.scenario else []
        edge_secure = [] if self.creds is None else ["--config", str(self.creds.mesh_config)]
        for i, home in enumerate(self.homes(a.uavs), start=1):
            ptcp, pudp = free_port_pair()
            self.start_service(f"uav{i}", [
                "edge", "--uav", str(i), *self.bus_args(f"uav{i}", "peer"), *edge_secure,
                *[x for e in multilink_endpoints(HOST, ptcp, pudp) for x in ("--listen", e)],
                "--home", ",".join(map(str, home)), "--speed", str(a.speed), "--epoch", str(self.epoch),
                "--seed", str(a.seed + i), "--camera", a.camera, *scenario])
        self.start_service("planner", ["planner", *self.bus_args("planner", "client")])
        self.start_service("detector", ["detector", *self.bus_args("detector", "client"), "--method", a.method])

    def check_alive(self) -> list[str]:
        return [s.name for s in self.group.services if not s.alive()]

    def stop(self) -> dict:
        codes = self.group.stop()
        for _, p in self.proxies:
            p.stop()
        if self.creds is not None:
            shutil.rmtree(self.creds.users_file.parent, ignore_errors=True)
        return codes


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=f"skynet {prog}", description=__doc__.split("\n\n")[0])
    p.add_argument("--uavs", type=int, default=3, help="number of UAVs")
    p.add_argument("--scenario", default=None, help="scenario file (default: the paper's monorail bridge)")
    p.add_argument("--speed", type=float, default=4.0, help="simulation speed factor (1 = real time)")
    p.add_argument("--camera", default="synthetic", help="synthetic | an image folder | video:<url>")
    p.add_argument("--method", default="it+", help="the detector's method")
    p.add_argument("--fleet", default="demo")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--impair", action="append", default=[], metavar="NAME=SPEC",
                   help='netem-like impairment between a node and the gateway, e.g. uav2="delay 50ms loss 2%%"')
    p.add_argument("--secure", action="store_true",
                   help="gateway authentication and access control, with generated per-service passwords")
    if prog == "mission":
        p.add_argument("--out", default=None, help="report folder (default reports/mission-<time>)")
        p.add_argument("--quiet", action="store_true", help="no live progress display")
        p.add_argument("--algorithm", default="theta-pso")
    return p


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    prog = argv.pop(0) if argv and argv[0] in ("up", "mission") else "up"
    args = build_parser(prog).parse_args(argv)
    log = setup_logging(prog)
    stop = stop_event_on_signals()
    if prog == "up":
        net = Network(args)
        try:
            net.start()
            log.info("network up: gateway at %s; Ctrl-C to stop", " ".join(net.gateway_endpoints))
            if net.creds is not None:
                log.info("authentication and access control on; users file (passwords) in %s",
                         net.creds.users_file.parent)
            while not stop.wait(1.0):
                dead = net.check_alive()
                if dead:
                    log.error("service(s) ended: %s", ", ".join(dead))
                    break
        finally:
            codes = net.stop()
            log.info("stopped: %s", codes)
        return 0
    return run_mission(args, log, stop)


def run_mission(args: argparse.Namespace, log: logging.Logger, stop) -> int:
    from services.gcs.cli import run_mission as gcs_mission
    from services.planner.scenario import load_scenario_document
    from services.gcs.mission import MissionOptions

    out = Path(args.out or f"reports/mission-{time.strftime('%Y%m%d-%H%M%S')}")
    out.mkdir(parents=True, exist_ok=True)
    log_file = open(out / "services.log", "w")
    net = Network(args, echo=log_file)
    scenario = load_scenario_document(args.scenario)
    try:
        net.start()
        cfg = net.gcs_config()
        options = MissionOptions(uavs=tuple(range(1, args.uavs + 1)), algorithm=args.algorithm, seed=args.seed,
                                 speed=args.speed)
        with Bus(cfg, fleet=args.fleet, name="gcs") as bus:
            code = gcs_mission(bus, scenario, options, str(out), args.quiet, log, abort=stop,
                               ground_truth=args.camera == "synthetic")
    finally:
        net.stop()
        log_file.close()
    log.info("services' logs: %s", out / "services.log")
    return code
