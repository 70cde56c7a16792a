"""The network a launcher run asks for, as data: every process, its endpoints, identity and command line.

:func:`network_plan` is a pure function of the launcher's options (:class:`LaunchOptions`: fleet size, sites,
impairments, faults, trust, autopilot, web/video/recording), the scenario, the trust decision and a source of
port numbers: it starts no process, opens no socket and no bus session. Its result (:class:`NetworkPlan`)
lists the processes in start order (:class:`ProcessSpec`: name, role, site, identity, the endpoints it listens
on and connects to, the environment it needs, its ``skynet`` argv), the impairment proxies
(:class:`ProxySpec`) and the small files the run needs (an edge's zenoh config). ``skynet up --dry-run``
prints it (:meth:`NetworkPlan.table`, :meth:`NetworkPlan.to_json`); :class:`services.orchestration.launcher.Network`
starts it.

Each role's argv is built by one function (``*_argv``), with the services' own flag names.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import socket
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from protocol import keys
from protocol.bus import multilink_endpoints
from protocol.links import LINK_LEASE_S
from protocol.scenario import Scenario

from . import sites as sitemap
from . import trustmode
from .faults import Resolved, cut_links, plan_faults
from .fleet_load import FleetLoad, fleet_load
from .topology import (
    Impairments,
    Links,
    MeshMode,
    edge_mesh_config,
    link_ends,
    link_seed,
    open_timeout_ms,
    parse_impair,
    skynet_link,
)

HOST = "127.0.0.1"
#: environment variable of the web page's access token (services.web.server.TOKEN_ENV)
WEB_TOKEN_ENV = "SKYNET_WEB_TOKEN"
#: environment variables whose values a printed plan does not show
SECRET_ENV = (WEB_TOKEN_ENV,)
#: a fleet above this many UAVs gives its planner the ground station's plan time and an anytime answer
ANYTIME_PLANNER_ABOVE = 24


@dataclass
class Plan:
    """What the command line asks of the network, checked: impairments, faults, proxied links, mesh."""

    links: Links
    impair: Impairments
    faults: list[Resolved]
    mesh: MeshMode
    proxied: set[str] = field(default_factory=set)
    #: the sites (one gateway each) and who attaches where (:mod:`.sites`)
    sites: sitemap.Mesh | None = None


def make_plan(args: Any, ground_station: bool) -> Plan:
    """Check ``--impair``, ``--fault`` and ``--mesh`` against the run; ValueError with a one-line message."""
    if args.uavs < 1:
        raise ValueError(f"--uavs {args.uavs}: at least one UAV")
    links = Links(args.uavs, ("planner", "detector", "gcs") if ground_station else ("planner", "detector"))
    impair = parse_impair(getattr(args, "impair", None) or [], links)
    faults = plan_faults(getattr(args, "fault", None) or [], links)
    detectors = getattr(args, "detectors", 1)
    if not 1 <= detectors <= args.uavs:
        raise ValueError(f"--detectors {detectors}: 1 to --uavs ({args.uavs}) instances")
    if detectors > 1 and any(r.service == "detector" for r in faults):
        raise ValueError("--fault kill detector: with --detectors N the instances are detector-0..N-1, which "
                         "faults do not name (cut detector cuts every instance's uplink)")
    proxied = set(impair.links()) | cut_links(faults)
    skynet = {link for link in proxied if link_ends(link) is not None}
    mesh = getattr(args, "mesh", None)
    if mesh is None:
        mesh = "proxied" if skynet else "direct"
    elif mesh == "direct" and skynet:
        raise ValueError(f"--mesh direct: SkyNet link(s) {', '.join(sorted(skynet))} are impaired or faulted, "
                         "which needs --mesh proxied")
    if mesh == "proxied":
        proxied |= set(links.skynet)
    n_sites = sitemap.check_sites(getattr(args, "sites", 1), args.uavs)
    rcus = ["planner", *(["detector"] if detectors == 1 else [f"detector-{k}" for k in range(detectors)])]
    if getattr(args, "netns", False):
        if getattr(args, "insecure", False):
            raise ValueError("--netns needs the default TLS links (both of a pair are TCP, which the forwarders "
                             "between namespaces carry): not with --insecure")
        if proxied or faults:
            raise ValueError("--netns with --impair/--fault: the launcher's link proxies run in the machine's own "
                             "namespace, not in the sites'; impair the router links with skynet netem by hand")
    where = sitemap.parse_rcu_sites(getattr(args, "rcu_site", None) or [], n_sites, rcus)
    if "detector" in proxied and len({s for n, s in where.items() if n.startswith("detector")}) > 1:
        raise ValueError("--impair/--fault on the detector link: its instances attach to different sites "
                         "(one proxy pair in front of one gateway): keep them at one site")
    return Plan(links, impair, faults, mesh, proxied, sitemap.mesh(args.uavs, n_sites, where))


@dataclass(frozen=True)
class LaunchOptions:
    """The options of ``skynet up`` / ``skynet mission`` the network depends on (the launcher's flags)."""

    uavs: int = 3
    fleet: str = keys.DEFAULT_FLEET
    scenario: str | None = None
    speed: float = 4.0
    camera: str = "synthetic"
    frame_size: str = "640x480"
    preview_hz: float | None = None
    gcs_state_hz: float | None = None
    edge_nice: int | None = None
    state_ingress_hz: float | None = None
    detect_max_mp: float | None = None
    capture_link: str = "auto"
    vehicle: str = "sim"
    autopilot_boot_scale: float = 1.0
    autopilot_firmware: str = "4.6"
    flight: str = "guided"
    method: str = "it+r"
    detectors: int = 1
    sites: int = 1
    rcu_site: tuple[str, ...] = ()
    seed: int = 0
    impair: tuple[str, ...] = ()
    mesh: str | None = None
    no_recovery: bool = False
    fault: tuple[str, ...] = ()
    keys: str | None = None
    accept_guard: bool = False
    insecure: bool = False
    netns: bool = False
    video: str | None = None
    video_sdp: str = "sdp"
    video_port: int = 5600
    web: str | None = None
    #: the detector's frame folder (``skynet mission``: the report's ``frames/``)
    save_frames: str | None = None

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> LaunchOptions:
        """The options of a parsed launcher command line (absent ones keep their defaults)."""
        out: dict[str, Any] = {}
        for name in cls.__dataclass_fields__:
            if hasattr(args, name):
                value = getattr(args, name)
                if isinstance(value, list):
                    value = tuple(value)
                if name == "frame_size" and isinstance(value, tuple):
                    value = f"{value[0]}x{value[1]}"
                out[name] = value
        return cls(**out)


@dataclass(frozen=True)
class Trust:
    """The trust decision a plan is made with: the key set's folder (None: unsigned), mutual TLS, and the
    router CA the nodes dial the gateways with (``gateway_dial``; None: their own CAs)."""

    keys: str | None = None
    tls: bool = False
    router_ca: str | None = None

    @classmethod
    def of(cls, keys: str | Path | None, tls: bool) -> Trust:
        """The trust of a key set folder: its router CA when it has one (read from the file system)."""
        router = None if keys is None else Path(keys) / "router-ca.pem"
        ca = str(router.resolve()) if router is not None and router.is_file() else None
        return cls(None if keys is None else str(keys), tls, ca)


#: a source of listening ports: ``ports("tcp")`` / ``ports("udp")``
Ports = Callable[[str], int]


class CountingPorts:
    """Ports counted up from ``start`` (a dry run, the unit tests: no socket is touched)."""

    def __init__(self, start: int = 7447):
        self._next = itertools.count(start)

    def __call__(self, kind: str = "tcp") -> int:
        return next(self._next)


def free_ports(kind: str = "tcp") -> int:
    """A free port of the machine (:func:`services.orchestration.process.free_port`): a real run."""
    from .process import free_port

    return free_port(socket.SOCK_STREAM if kind == "tcp" else socket.SOCK_DGRAM)


@dataclass(frozen=True)
class ProcessSpec:
    """One process of the network.

    ``argv`` follows ``python -m services.cli`` (empty for the in-process ground station of ``skynet
    mission``); ``identity`` is the key set's identity it runs as (None: no bus, or no key set);
    ``namespace`` the site whose network namespace it runs in (``--netns``; None: the machine's own);
    ``ready``: it signals when it is up (:mod:`protocol.readiness`) and is supervised as a service;
    ``wait``: the launcher waits for that signal before starting the next process.
    """

    name: str
    role: str
    site: int
    identity: str | None
    listens: tuple[str, ...] = ()
    connects: tuple[str, ...] = ()
    env: dict[str, str] = field(default_factory=dict)
    argv: tuple[str, ...] = ()
    ready: bool = True
    wait: bool = False
    namespace: int | None = None
    in_process: bool = False


@dataclass(frozen=True)
class ProxySpec:
    """The impairment proxies of one link: one per reliability class, listening on ``ports`` (tcp, udp)
    in front of ``targets`` (host:port of the tcp and udp ends); ``udp_kind`` is ``tcp`` when the
    best-effort class is a TLS stream (both links of a TLS pair are TCP)."""

    link: str
    ports: tuple[int, int]
    targets: tuple[str, str]
    udp_kind: str
    impairments: tuple[str | None, str | None]
    seeds: tuple[int, int]

    def endpoints(self) -> list[str]:
        """Where a node dials to go through these proxies."""
        if self.udp_kind == "tcp":
            return trustmode.tls_endpoints(HOST, *self.ports)
        return multilink_endpoints(HOST, *self.ports)


@dataclass
class NetworkPlan:
    """The processes (in start order), proxies, files and sites of one run."""

    fleet: str
    processes: list[ProcessSpec]
    proxies: dict[str, ProxySpec]
    #: path -> content of the files the run writes before starting (mode 0600)
    files: dict[str, str]
    site_endpoints: list[list[str]]
    checked: Plan
    trust: Trust
    load: FleetLoad
    ground_station: bool = False
    homes: list[tuple[float, float, float]] = field(default_factory=list)

    @property
    def gateway_endpoints(self) -> list[str]:
        return self.site_endpoints[0]

    def get(self, name: str) -> ProcessSpec:
        for p in self.processes:
            if p.name == name:
                return p
        raise KeyError(f"no process named {name!r} in the plan")

    def topology(self) -> list[str]:
        """One line per site: its gateway, where it listens and dials, and the nodes attached to it."""
        out = []
        for site in self.checked.sites.sites:
            dials = ", ".join(sitemap.gateway_process(j) for j in self.checked.sites.peers_of(site.index))
            nodes = [*(f"uav{u}" for u in site.uavs), *(["gcs"] if site.index == 0 and self.ground_station else []),
                     *site.rcus]
            out.append(f"site {site.index}: {sitemap.gateway_process(site.index)} at "
                       f"{' '.join(self.site_endpoints[site.index])}" + (f" dialling {dials}" if dials else "")
                       + f"; attached: {' '.join(nodes) or 'nothing'}")
        return out

    def to_json(self) -> dict[str, Any]:
        """The plan as JSON-ready data; secret environment values are shown as ``***``."""
        def proc(p: ProcessSpec) -> dict[str, Any]:
            d = asdict(p)
            d["env"] = {k: ("***" if k in SECRET_ENV else v) for k, v in p.env.items()}
            d["listens"], d["connects"], d["argv"] = list(p.listens), list(p.connects), list(p.argv)
            return d

        return {"fleet": self.fleet, "uavs": self.checked.links.uavs, "mesh": self.checked.mesh,
                "trust": {"keys": self.trust.keys, "tls": self.trust.tls},
                "sites": [{"index": s.index, "gateway": sitemap.gateway_process(s.index),
                           "endpoints": self.site_endpoints[s.index], "uavs": list(s.uavs), "rcus": list(s.rcus)}
                          for s in self.checked.sites.sites],
                "homes": [list(h) for h in self.homes],
                "processes": [proc(p) for p in self.processes],
                "proxies": [{**asdict(x), "endpoints": x.endpoints()} for x in self.proxies.values()],
                "files": sorted(self.files),
                "faults": [r.fault.text for r in self.checked.faults]}

    def table(self) -> str:
        """A readable table of the processes, then each one's command line, the proxies and the sites."""
        head = ("NAME", "ROLE", "SITE", "IDENTITY", "LISTENS", "CONNECTS", "ENV")
        rows = [head]
        for p in self.processes:
            rows.append((p.name, p.role + (" (in-process)" if p.in_process else ""), str(p.site), p.identity or "-",
                         " ".join(p.listens) or "-", " ".join(e.split("#")[0] for e in p.connects) or "-",
                         " ".join(sorted(p.env)) or "-"))
        widths = [max(len(r[k]) for r in rows) for k in range(len(head))]
        lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
        lines += ["", "commands (python -m services.cli ...):"]
        lines += [f"  {p.name}: skynet {' '.join(p.argv)}" for p in self.processes if p.argv]
        if self.proxies:
            lines += ["", "proxies:"]
            lines += [f"  {x.link}: tcp :{x.ports[0]} -> {x.targets[0]} ({x.impairments[0] or 'clean'}), "
                      f"{x.udp_kind} :{x.ports[1]} -> {x.targets[1]} ({x.impairments[1] or 'clean'})"
                      for x in self.proxies.values()]
        lines += ["", "sites:", *(f"  {t}" for t in self.topology())]
        lines += ["", f"trust: {'mutual TLS, key set ' + str(self.trust.keys) if self.trust.tls else 'INSECURE'}"]
        return "\n".join(lines)


# -- homes and the fence from the scenario


def fleet_offsets(scenario: Scenario, n: int) -> list[tuple[float, float, float]]:
    """The formation offsets ΔT_n of an ``n``-UAV fleet (P9): the scenario's own when it has one per UAV, else
    :func:`edge.geometry.formation.offsets_for` (as the ground station plans with, ``services.gcs.mission``)."""
    if len(scenario.formation.offsets) == n:
        return [tuple(map(float, o)) for o in scenario.formation.offsets]
    from edge.geometry.formation import offsets_for

    return [tuple(map(float, o)) for o in offsets_for(n)]


def homes(scenario: Scenario, n: int) -> list[tuple[float, float, float]]:
    """Launch points: the formation slots of the scenario's offsets around its start, rotated to the start→goal
    heading, on the box's floor (P9); a UAV stacked above another launches beside it
    (:func:`edge.geometry.formation.home_offsets`)."""
    from edge.geometry.formation import home_offsets, rotation_of

    start, goal = scenario.start, scenario.goal
    yaw = math.atan2(goal[1] - start[1], goal[0] - start[0])
    R = rotation_of(0.0, 0.0, yaw)
    ground = scenario.box.lo[2]
    out = []
    for xy in home_offsets(fleet_offsets(scenario, n)):
        p = (R @ (xy[0], xy[1], 0.0))[:2]
        out.append((round(float(start[0] + p[0]), 3), round(float(start[1] + p[1]), 3), float(ground)))
    return out


def fence_arg(scenario: Scenario) -> str:
    """The scenario's operation box as the edge's ``--geofence x0,y0,z0,x1,y1,z1``: the ceiling a signed
    upload may only narrow (:func:`edge.geometry.validate.narrowed_fence`)."""
    return ",".join(f"{v:g}" for v in (*scenario.box.lo, *scenario.box.hi))


# -- one argv per role (the services' own flag names)


def bus_argv(o: LaunchOptions, trust: Trust, mode: str, connects: list[str], client_lease: list[str]) -> list[str]:
    """The session options every node shares: mode, fleet, the multilink pair, its gateway, its key set."""
    out = ["--mode", mode, "--fleet", o.fleet, "--multilink", *(client_lease if mode == "client" else [])]
    for e in connects:
        out += ["--connect", e]
    return out + key_argv(trust)


def key_argv(trust: Trust) -> list[str]:
    return [] if trust.keys is None else ["--keys", str(trust.keys)]


def gateway_argv(o: LaunchOptions, trust: Trust, ident: str | None, lease: list[str], thin: list[str],
                 connects: list[str], listens: list[str]) -> list[str]:
    return ["gateway", *(["--id", ident] if ident else []), "--fleet", o.fleet, "--multilink", *lease, *thin,
            *(["--accept-guard"] if o.accept_guard else []), *key_argv(trust),
            *[x for e in connects for x in ("--connect", e)], *[x for e in listens for x in ("--listen", e)]]


def autopilot_argv(o: LaunchOptions, i: int, port: int, home: tuple[float, float, float], epoch: float) -> list[str]:
    return ["sim-autopilot", "--uav", str(i), "--port-base", str(port - i + 1), "--home", ",".join(map(str, home)),
            "--speed", str(o.speed), "--epoch", str(epoch), "--seed", str(o.seed + i), "--wind", "moderate",
            "--boot-scale", f"{o.autopilot_boot_scale:g}", "--firmware-version", o.autopilot_firmware]


def edge_argv(o: LaunchOptions, i: int, bus: list[str], mesh: list[str], config: list[str], listens: list[str],
              home: tuple[float, float, float], epoch: float, fence: str, load: FleetLoad,
              mavlink_port: int | None) -> list[str]:
    vehicle = [] if mavlink_port is None else ["--vehicle", "mavlink", "--mavlink", f"udpin:{HOST}:{mavlink_port}",
                                               "--flight", o.flight]
    return ["edge", "--uav", str(i), *bus, *mesh, *config, *[x for e in listens for x in ("--listen", e)],
            "--home", ",".join(map(str, home)), "--speed", str(o.speed), "--epoch", str(epoch),
            "--seed", str(o.seed + i), "--camera", o.camera, "--frame-size", o.frame_size,
            "--capture-link", o.capture_link, "--preview-hz", f"{load.preview_hz:g}",
            *(["--nice", str(load.edge_nice)] if load.edge_nice else []),
            *(["--scenario", o.scenario] if o.scenario else []), "--geofence", fence,
            *(["--imagery-cache", "0"] if o.no_recovery else []), *vehicle]


def planner_argv(o: LaunchOptions, bus: list[str]) -> list[str]:
    # a large fleet's plan is computed while its edges load the machine: the planner may take up to 100 s of the
    # ground station's 120 s plan timeout instead of its own 60 s default, and then answers with the best
    # collision-free path it found (48 edges left it 157 of 300 iterations)
    budget = ["--time-budget", "100", "--anytime"] if o.uavs > ANYTIME_PLANNER_ABOVE else []
    return ["planner", *bus, *budget]


def detector_argv(o: LaunchOptions, bus: list[str], k: int, n: int) -> list[str]:
    part = [] if n == 1 else ["--partition", f"{k}/{n}", "--max-uav", str(o.uavs)]
    return ["detector", *bus, "--method", o.method, *part, *(["--no-recovery"] if o.no_recovery else []),
            *(["--save-frames", o.save_frames] if o.save_frames else []),
            *([] if o.detect_max_mp is None else ["--detect-max-mp", str(o.detect_max_mp)])]


def video_argv(o: LaunchOptions, bus: list[str]) -> list[str]:
    return ["video", *bus, "--codec", str(o.video), "--uavs", str(o.uavs), "--sdp-dir", str(o.video_sdp),
            "--port", str(o.video_port)]


def web_argv(o: LaunchOptions, bus: list[str]) -> list[str]:
    return ["web", *bus, "--listen-web", str(o.web), *(["--scenario", o.scenario] if o.scenario else [])]


def netem_link_argv(local: int, target: str) -> list[str]:
    return ["netem", "tcp", "--listen", f"{HOST}:{local}", "--target", target, "--interval", "60"]


def bridge_argv(listen: str, target: str) -> list[str]:
    return ["bridge", "--listen", listen, "--target", target]


# -- the plan


def gateway_thinning(o: LaunchOptions, load: FleetLoad) -> list[str]:
    """The gateways' traffic options: ``--state-ingress-hz`` when given (else the gateway's default per-face
    limit, :mod:`services.gateway.ingress`), and with ``--gcs-state-hz`` a ``--cfg downsampling:[...]`` that
    thins the clients' view of the states (:mod:`services.gateway.downsample`)."""
    out = [] if o.state_ingress_hz is None else ["--state-ingress-hz", str(o.state_ingress_hz)]
    if load.gcs_state_hz <= 0:
        return out
    from ..gateway.downsample import state_downsampling

    rules = state_downsampling(o.fleet, load.gcs_state_hz, o.uavs)
    return out + [a for k, v in rules.items() for a in ("--cfg", f"{k}:{json.dumps(v)}")]


def network_plan(o: LaunchOptions, scenario: Scenario, trust: Trust, ports: Ports, *, ground_station: bool = False,
                 epoch: float = 0.0, workdir: str = "run", web_token: str = "", checked: Plan | None = None
                 ) -> NetworkPlan:
    """The network of a launcher run (module docstring): no process, socket or session; ValueError (one line)
    for options that do not fit together (:func:`make_plan`)."""
    checked = checked or make_plan(o, ground_station)
    load = fleet_load(o.uavs, o.gcs_state_hz, o.preview_hz, o.edge_nice)
    timeout = open_timeout_ms(checked.impair.worst_delay_ms())
    mesh_sites = checked.sites

    def pair() -> list[str]:
        if trust.tls:
            return trustmode.tls_endpoints(HOST, ports("tcp"), ports("tcp"))
        return multilink_endpoints(HOST, ports("tcp"), ports("udp"))

    site_endpoints = [pair() for _ in mesh_sites.sites]
    proxies: dict[str, ProxySpec] = {}
    files: dict[str, str] = {}
    procs: list[ProcessSpec] = []

    def proxy(link: str, target: list[str]) -> list[str]:
        if link not in proxies:
            tls = all(e.startswith("tls/") for e in target)
            t_tcp, t_udp = (e.split("/", 1)[1].split("?")[0].split("#")[0] for e in target)
            proxies[link] = ProxySpec(link, (ports("tcp"), ports("tcp" if tls else "udp")), (t_tcp, t_udp),
                                      "tcp" if tls else "udp",
                                      (checked.impair.spec(link, "tcp"), checked.impair.spec(link, "udp")),
                                      (link_seed(o.seed, link, "tcp"), link_seed(o.seed, link, "udp")))
        return proxies[link].endpoints()

    def site_of(name: str) -> int:
        if name.startswith("uav") and name[3:].isdigit():
            return mesh_sites.site_of(int(name[3:]))
        if name == "detector":  # also the instances' shared link name: make_plan keeps a proxied one at one site
            return min((s.index for s in mesh_sites.sites for r in s.rcus if r.startswith("detector")), default=0)
        try:
            return mesh_sites.site_of(name)
        except KeyError:
            return 0

    def uplink(link: str, site: int) -> list[str]:
        """Where a node dials its gateway: the site's endpoints, or the proxies of its uplink."""
        target = site_endpoints[site]
        ends = proxy(link, target) if link in checked.proxied else target
        return [trustmode.dial_with_ca(e, trust.router_ca) for e in ends]

    # proxied links: the edges' lease on the ground too (protocol.links.LINK_LEASE_S), and the clients' open
    # timeout the edges' (topology.OPEN_TIMEOUT_MS): a UDP handshake lost on an impaired link is retried in seconds
    lease = ["--lease", str(LINK_LEASE_S)] if checked.proxied else []
    client_lease = [*lease, "--cfg", f"transport/unicast/open_timeout:{json.dumps(timeout)}"] if checked.proxied else []
    netns = o.netns
    thin = gateway_thinning(o, load)
    ident = None if trust.keys is None else "gateway"
    for site in mesh_sites.sites:  # one gateway per site, each dialling the lower-numbered ones
        name = sitemap.gateway_process(site.index)
        peers = mesh_sites.peers_of(site.index)
        targets: list[str] = []
        for j in peers:
            if not netns:
                targets += site_endpoints[j]
                continue
            addresses = sitemap.veth_addresses(mesh_sites.links)
            i0, j0 = sorted((site.index, j))
            a, b = addresses[(i0, j0)]
            peer_address = (a if j == i0 else b).split("/")[0]
            for e in site_endpoints[j]:  # through the project's TCP proxy in this site's namespace to j's veth
                port = int(e.split("?")[0].rsplit(":", 1)[1])
                local = ports("tcp")
                procs.append(ProcessSpec(f"link-{name}-{sitemap.gateway_process(j)}-{port}", "link", site.index,
                                         None, (f"{HOST}:{local}",), (f"{peer_address}:{port}",),
                                         argv=tuple(netem_link_argv(local, f"{peer_address}:{port}")), wait=True,
                                         namespace=site.index))
                targets.append(e.replace(f"{HOST}:{port}", f"{HOST}:{local}"))
        listen = site_endpoints[site.index]
        if netns:  # also on its veths, for the router links' proxies
            listen = [e.replace(f"/{HOST}:", "/0.0.0.0:") for e in listen]
        dials = [trustmode.dial_with_ca(e, trust.router_ca) for e in targets]
        procs.append(ProcessSpec(name, "gateway", site.index, ident, tuple(listen), tuple(dials),
                                 argv=tuple(gateway_argv(o, trust, None if len(site_endpoints) == 1 else site.gateway,
                                                         lease, thin, dials, listen)),
                                 wait=True, namespace=site.index if netns else None))
        if netns and site.index == 0:  # site 0's gateway reached from the machine's own namespace
            for e in site_endpoints[0]:
                port = int(e.split("?")[0].rsplit(":", 1)[1])
                sock = f"{workdir}/gateway-{port}.sock"
                procs.append(ProcessSpec(f"bridge-in-{port}", "bridge", 0, None, (f"unix:{sock}",),
                                         (f"tcp:{HOST}:{port}",),
                                         argv=tuple(bridge_argv(f"unix:{sock}", f"tcp:{HOST}:{port}")), wait=True,
                                         namespace=0))
                procs.append(ProcessSpec(f"bridge-out-{port}", "bridge", 0, None, (f"tcp:{HOST}:{port}",),
                                         (f"unix:{sock}",),
                                         argv=tuple(bridge_argv(f"tcp:{HOST}:{port}", f"unix:{sock}")), wait=True))

    launch = homes(scenario, o.uavs)
    fence = fence_arg(scenario)
    edge_endpoints = {i: pair() for i in range(1, o.uavs + 1)}
    formations = o.uavs > sitemap.FORMATION_SIZE  # several formations: no gossip autoconnect
    from edge.geometry.neighbourhood import members

    for i, home in enumerate(launch, start=1):
        name = f"uav{i}"
        ns = mesh_sites.site_of(i) if netns else None
        mav = None
        if o.vehicle == "mavlink":  # a sim autopilot per UAV, on loopback UDP, beside its edge
            mav = ports("udp")
            procs.append(ProcessSpec(f"ap{i}", "autopilot", mesh_sites.site_of(i), None, (f"udp/{HOST}:{mav}",),
                                     argv=tuple(autopilot_argv(o, i, mav, home, epoch)), ready=False, namespace=ns))
        connects = uplink(name, mesh_sites.site_of(i))
        mesh: list[str] = []
        for j in (j for j in members(i, fleet=o.uavs) if j > i):  # its formation's later edges
            ends = proxy(skynet_link(i, j), edge_endpoints[j]) if checked.mesh == "proxied" else edge_endpoints[j]
            for e in ends:
                mesh += ["--connect", e]
        config: list[str] = []
        if checked.mesh != "direct" or name in checked.proxied or formations:
            path = f"{workdir}/{name}.json5"
            files[path] = json.dumps(edge_mesh_config("proxied" if formations else checked.mesh, None, timeout))
            config = ["--config", path]
        bus = bus_argv(o, trust, "peer", connects, client_lease)
        procs.append(ProcessSpec(name, "edge", mesh_sites.site_of(i), None if trust.keys is None else name,
                                 tuple(edge_endpoints[i]), (*connects, *mesh[1::2]),
                                 argv=tuple(edge_argv(o, i, bus, mesh, config, edge_endpoints[i], home, epoch, fence,
                                                      load, mav)), namespace=ns))

    def client(name: str, role: str, link: str, argv: Callable[[list[str]], list[str]], identity: str,
               main_namespace: bool = False, env: dict[str, str] | None = None) -> None:
        site = site_of(name)
        connects = uplink(link, site)
        procs.append(ProcessSpec(name, role, site, None if trust.keys is None else identity, (), tuple(connects),
                                 env=dict(env or {}), argv=tuple(argv(bus_argv(o, trust, "client", connects,
                                                                               client_lease))),
                                 namespace=site if netns and not main_namespace else None))

    client("planner", "planner", "planner", lambda bus: planner_argv(o, bus), "planner")
    n = o.detectors  # N instances share the cameras by UAV id (services.detector.partition)
    for k in range(n):
        client("detector" if n == 1 else f"detector-{k}", "detector", "detector",
               lambda bus, k=k: detector_argv(o, bus, k, n), "detector")
    if o.video:  # skynet video: RTP/UDP to loopback, UAV 1 on 5600 (services.video)
        client("video", "video", "video", lambda bus: video_argv(o, bus), "video", main_namespace=True)
    if o.web and not ground_station:  # skynet up: the page as its own process, its token in its environment
        client("web", "web", "web", lambda bus: web_argv(o, bus), "web", main_namespace=True,
               env={WEB_TOKEN_ENV: web_token})
    if ground_station:  # skynet mission: the ground station runs in the launcher's own process
        connects = uplink("gcs", 0)
        procs.append(ProcessSpec("gcs", "gcs", 0, None if trust.keys is None else "gcs", (), tuple(connects),
                                 ready=False, in_process=True))
    return NetworkPlan(o.fleet, procs, proxies, files, site_endpoints, checked, trust, load, ground_station, launch)
