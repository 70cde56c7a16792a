"""The network a launcher run asks for, as data: every process, its endpoints, identity and command line.

Design notes: docs/architecture.md (services/orchestration/plan.py).
"""

from __future__ import annotations

import itertools
import json
import math
import socket
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

from edge.config import FRAME_SIZE, EdgeConfig
from protocol.bus import multilink_endpoints
from protocol.cliconfig import one_line, to_argv
from protocol.links import LINK_LEASE_S
from protocol.messages import Box
from protocol.scenario import Scenario

from ..detector.config import DetectorConfig
from ..gateway.config import GatewayConfig
from ..planner.config import PlannerConfig
from ..video.config import VideoConfig
from . import sites as sitemap
from . import trustmode
from .config import LaunchConfig
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
C = TypeVar("C", bound=BaseModel)
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


def make_plan(o: LaunchConfig, ground_station: bool) -> Plan:
    """Check ``--impair``, ``--fault`` and ``--mesh`` against the run; ValueError with a one-line message."""
    links = Links(o.uavs, ("planner", "detector", "gcs") if ground_station else ("planner", "detector"))
    impair = parse_impair(o.impair, links)
    faults = plan_faults(o.fault, links)
    if not 1 <= o.detectors <= o.uavs:
        raise ValueError(f"--detectors {o.detectors}: 1 to --uavs ({o.uavs}) instances")
    if o.detectors > 1 and any(r.service == "detector" for r in faults):
        raise ValueError("--fault kill detector: with --detectors N the instances are detector-0..N-1, which "
                         "faults do not name (cut detector cuts every instance's uplink)")
    proxied = set(impair.links()) | cut_links(faults)
    skynet = {link for link in proxied if link_ends(link) is not None}
    mesh = o.mesh
    if mesh is None:
        mesh = "proxied" if skynet else "direct"
    elif mesh == "direct" and skynet:
        raise ValueError(f"--mesh direct: SkyNet link(s) {', '.join(sorted(skynet))} are impaired or faulted, "
                         "which needs --mesh proxied")
    if mesh == "proxied":
        proxied |= set(links.skynet)
    n_sites = sitemap.check_sites(o.sites, o.uavs)
    rcus = ["planner", *(["detector"] if o.detectors == 1 else [f"detector-{k}" for k in range(o.detectors)])]
    if o.netns:
        if o.insecure:
            raise ValueError("--netns needs the default TLS links (both of a pair are TCP, which the forwarders "
                             "between namespaces carry): not with --insecure")
        if proxied or faults:
            raise ValueError("--netns with --impair/--fault: the launcher's link proxies run in the machine's own "
                             "namespace, not in the sites'; impair the router links with skynet netem by hand")
    where = sitemap.parse_rcu_sites(o.rcu_site, n_sites, rcus)
    if "detector" in proxied and len({s for n, s in where.items() if n.startswith("detector")}) > 1:
        raise ValueError("--impair/--fault on the detector link: its instances attach to different sites "
                         "(one proxy pair in front of one gateway): keep them at one site")
    return Plan(links, impair, faults, mesh, proxied, sitemap.mesh(o.uavs, n_sites, where))


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
    """One process of the network. ``argv`` (after ``python -m services.cli``) is rendered from ``config``
    (:func:`protocol.cliconfig.to_argv`), by hand for a process without a config model, both empty for the
    in-process ground station of ``skynet mission``."""

    name: str
    role: str
    site: int
    identity: str | None  # the key set's identity it runs as (None: no bus, or no key set)
    listens: tuple[str, ...] = ()
    connects: tuple[str, ...] = ()
    env: dict[str, str] = field(default_factory=dict)
    argv: tuple[str, ...] = ()
    ready: bool = True  # it signals when it is up (protocol.readiness) and is supervised as a service
    wait: bool = False  # the launcher waits for that signal before starting the next process
    namespace: int | None = None  # the site whose network namespace it runs in (--netns; None: the machine's own)
    in_process: bool = False
    config: BaseModel | None = None  # the service's typed configuration


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


def own_speed_warning(speed: float) -> str:
    """What a user flying their own autopilots at a mission speed other than real time is told."""
    return (f"--speed {speed:g} runs the mission's clock at {speed:g}x real time: a real vehicle (or ArduPilot SITL "
            "without --speedup) needs --speed 1; a sim autopilot started with the same --speed keeps up")


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
            d = asdict(replace(p, config=None))
            d["config"] = None if p.config is None else p.config.model_dump(mode="json")
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

    def autopilot_lines(self) -> list[str]:
        """With MAVLink vehicles: each edge's autopilot (its own at an endpoint, or the sim one the run starts)."""
        names = {p.name for p in self.processes}
        out = []
        for p in self.processes:
            cfg = p.config
            if p.role != "edge" or getattr(cfg, "vehicle", "sim") != "mavlink":
                continue
            sim = f"ap{cfg.uav}" in names
            home = "its autopilot's home" if getattr(cfg, "home_from_autopilot", False) else \
                f"home {','.join(f'{v:g}' for v in cfg.home)}"
            out.append(f"  {p.name}: {'sim autopilot ap' + str(cfg.uav) if sim else 'its own autopilot'} at "
                       f"{cfg.mavlink}, {cfg.flight}, {home}")
        speeds = {p.config.speed for p in self.processes if p.role == "edge" and p.config is not None}
        if any("its own" in line for line in out) and speeds != {1.0}:
            out.append(f"  note: {own_speed_warning(max(speeds))}")
        return ["", "autopilots (MAVLink):", *out] if out else []

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
        lines += self.autopilot_lines()
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


# -- one argv per role (the services' own flag names)


def child(name: str, model: type[C], **values: Any) -> C:
    """``name``'s configuration: the values checked by the service's own model, so that a value it would refuse
    fails in the plan (ValueError, one line) instead of in its log."""
    try:
        return model.model_validate(values)
    except ValidationError as exc:
        raise ValueError(f"{name} would refuse its options: {one_line(exc)}") from None


def session(o: LaunchConfig, trust: Trust, connects: list[str], lease: dict[str, Any]) -> dict[str, Any]:
    """The session options every node shares: fleet, the multilink pair, its gateway, its key set (and on proxied
    links a client's lease and open timeout)."""
    return {"fleet": o.fleet, "multilink": True, "connect": connects, "keys": trust.keys, **lease}


def autopilot_argv(o: LaunchConfig, i: int, port: int, home: tuple[float, float, float], epoch: float,
                   origin: tuple[float, float, float] | None = None) -> list[str]:
    """The sim autopilot's command line (its parser is the edge's vehicle package's, not a config model);
    ``origin``: the scenario's geodetic origin, where its HOME_POSITION is reckoned from."""
    return ["sim-autopilot", "--uav", str(i), "--port-base", str(port - i + 1), "--home=" + ",".join(map(str, home)),
            "--speed", str(o.speed), "--epoch", str(epoch), "--seed", str(o.seed + i), "--wind", "moderate",
            "--boot-scale", f"{o.sim_boot_scale:g}", "--firmware-version", o.sim_firmware_version,
            *(["--legacy-mission-request"] if o.sim_legacy_mission_request else []),
            *(["--rc-centred"] if o.sim_rc_centred else []),
            "--firmware", o.sim_firmware,
            *(["--origin=" + ",".join(f"{v:.9g}" for v in origin)] if origin is not None else [])]


def capture_size(o: LaunchConfig, scenario: Scenario) -> tuple[int, int]:
    """The edges' capture frame size: the user's, else the camera's own resolution when the scenario asks for full
    frames (``camera.full_frames``: cracks of real size), else the edge's default."""
    if o.frame_size is not None:
        return o.frame_size
    return scenario.camera.resolution if scenario.camera.full_frames else FRAME_SIZE


def edge_config(o: LaunchConfig, i: int, bus: dict[str, Any], listens: list[str], home: tuple[float, float, float],
                epoch: float, fence: Box, load: FleetLoad, mavlink: int | str | None,
                frame_size: tuple[int, int] = FRAME_SIZE) -> EdgeConfig:
    """The edge's config; its ``geofence`` the scenario's operation box, the ceiling a signed upload may only narrow
    (:func:`edge.geometry.validate.narrowed_fence`). ``mavlink``: its sim autopilot's loopback port, or its own
    autopilot's endpoint (``--autopilot``), or None (the built-in vehicle)."""
    vehicle: dict[str, Any] = {}
    if mavlink is not None:
        endpoint = f"udpin:{HOST}:{mavlink}" if isinstance(mavlink, int) else mavlink
        vehicle = {"vehicle": "mavlink", "mavlink": endpoint, "flight": o.flight,
                   **({"home_from_autopilot": True} if o.home_from_autopilot else {})}
    return child(f"uav{i}", EdgeConfig, uav=i, **bus, listen=listens, home=home, speed=o.speed, epoch=epoch,
                 seed=o.seed + i, camera=o.camera, frame_size=frame_size, capture_link=o.capture_link,
                 preview_hz=load.preview_hz, nice=load.edge_nice, scenario=o.scenario, geofence=fence,
                 **({"imagery_cache": 0} if o.no_recovery else {}), **vehicle)


def planner_config(o: LaunchConfig, bus: dict[str, Any]) -> PlannerConfig:
    # a large fleet's plan is computed while its edges load the machine: the planner may take up to 100 s of the
    # ground station's 120 s plan timeout instead of its own 60 s default, and then answers with the best
    # collision-free path it found (48 edges left it 157 of 300 iterations)
    budget = {"time_budget": 100.0, "anytime": True} if o.uavs > ANYTIME_PLANNER_ABOVE else {}
    return child("planner", PlannerConfig, **bus, **budget)


def detector_config(o: LaunchConfig, bus: dict[str, Any], k: int, n: int) -> DetectorConfig:
    part = {} if n == 1 else {"partition": f"{k}/{n}", "max_uav": o.uavs}
    return child("detector" if n == 1 else f"detector-{k}", DetectorConfig, **bus, method=o.method, **part,
                 no_recovery=o.no_recovery, save_frames=o.save_frames,
                 **({} if o.detect_max_mp is None else {"detect_max_mp": o.detect_max_mp}))


def video_config(o: LaunchConfig, bus: dict[str, Any]) -> VideoConfig:
    return child("video", VideoConfig, **bus, codec=o.video, uavs=o.uavs, sdp_dir=o.video_sdp, port=o.video_port)


def web_config(o: LaunchConfig, bus: dict[str, Any]):
    from services.web.config import WebConfig  # the page's server (aiohttp) only when a page is asked for

    return child("web", WebConfig, **bus, listen_web=o.web, scenario=o.scenario)


def netem_link_argv(local: int, target: str) -> list[str]:
    return ["netem", "tcp", "--listen", f"{HOST}:{local}", "--target", target, "--interval-s", "60"]


def bridge_argv(listen: str, target: str) -> list[str]:
    return ["bridge", "--listen", listen, "--target", target]


def spec(name: str, role: str, site: int, identity: str | None, config: BaseModel, **kw: Any) -> ProcessSpec:
    """A process that runs ``skynet ROLE`` with ``config``: its command line rendered from it."""
    return ProcessSpec(name, role, site, identity, argv=(role, *to_argv(config)), config=config, **kw)


# -- the plan


def gateway_thinning(o: LaunchConfig, load: FleetLoad) -> dict[str, Any]:
    """The gateways' traffic options: ``state_ingress_hz`` when given (else the gateway's default per-face
    limit, :mod:`services.gateway.ingress`), and with ``--gcs-state-hz`` a ``cfg`` ``downsampling:[...]`` that
    thins the clients' view of the states (:mod:`services.gateway.downsample`)."""
    out: dict[str, Any] = {} if o.state_ingress_hz is None else {"state_ingress_hz": o.state_ingress_hz}
    if load.gcs_state_hz <= 0:
        return out
    from ..gateway.downsample import state_downsampling

    rules = state_downsampling(o.fleet, load.gcs_state_hz, o.uavs)
    return {**out, "cfg": [(k, json.dumps(v)) for k, v in rules.items()]}


def network_plan(o: LaunchConfig, scenario: Scenario, trust: Trust, ports: Ports, *, ground_station: bool = False,
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
    lease: dict[str, Any] = {"lease": LINK_LEASE_S} if checked.proxied else {}
    client_lease = {**lease, "cfg": [("transport/unicast/open_timeout", json.dumps(timeout))]} if lease else {}
    netns = o.netns
    thin = gateway_thinning(o, load)
    ident = None if trust.keys is None else "gateway"
    for site in mesh_sites.sites:  # one gateway per site, each dialling the lower-numbered ones
        name = sitemap.gateway_process(site.index)
        peers = mesh_sites.peers_of(site.index)
        targets: list[str] = []
        for j in peers:
            # one link per router link: two links between routers let a declaration overtake the link state it
            # refers to, and the other router drops it for good (bench/router_links.py)
            router_link = site_endpoints[j][:1]
            if not netns:
                targets += router_link
                continue
            addresses = sitemap.veth_addresses(mesh_sites.links)
            i0, j0 = sorted((site.index, j))
            a, b = addresses[(i0, j0)]
            peer_address = (a if j == i0 else b).split("/")[0]
            for e in router_link:  # through the project's TCP proxy in this site's namespace to j's veth
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
        gw = child(name, GatewayConfig, **session(o, trust, dials, lease), **thin, listen=listen,
                   no_accept_guard=o.no_accept_guard, **({} if len(site_endpoints) == 1 else {"id": site.gateway}))
        procs.append(spec(name, "gateway", site.index, ident, gw, listens=tuple(listen), connects=tuple(dials),
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
    fence = Box(lo=scenario.box.lo, hi=scenario.box.hi)
    edge_endpoints = {i: pair() for i in range(1, o.uavs + 1)}
    formations = o.uavs > sitemap.FORMATION_SIZE  # several formations: no gossip autoconnect
    from edge.geometry.neighbourhood import members

    own = o.autopilots()  # --autopilot: UAVs that fly their own autopilot (no sim one started)
    origin = (scenario.origin.lat, scenario.origin.lon, scenario.origin.alt)
    for i, home in enumerate(launch, start=1):
        name = f"uav{i}"
        ns = mesh_sites.site_of(i) if netns else None
        mav: int | str | None = own.get(i)
        if o.vehicle == "mavlink" and mav is None:  # a sim autopilot per other UAV, on loopback UDP, beside its edge
            mav = ports("udp")
            procs.append(ProcessSpec(f"ap{i}", "autopilot", mesh_sites.site_of(i), None, (f"udp/{HOST}:{mav}",),
                                     argv=tuple(autopilot_argv(o, i, mav, home, epoch, origin)), ready=False,
                                     namespace=ns))
        connects = uplink(name, mesh_sites.site_of(i))
        mesh: list[str] = []
        for j in (j for j in members(i, fleet=o.uavs) if j > i):  # its formation's later edges
            mesh += proxy(skynet_link(i, j), edge_endpoints[j]) if checked.mesh == "proxied" else edge_endpoints[j]
        bus = session(o, trust, [*connects, *mesh], {})
        if checked.mesh != "direct" or name in checked.proxied or formations:
            bus["config"] = path = f"{workdir}/{name}.json5"
            files[path] = json.dumps(edge_mesh_config("proxied" if formations else checked.mesh, None, timeout))
        edge = edge_config(o, i, bus, edge_endpoints[i], home, epoch, fence, load, mav, capture_size(o, scenario))
        procs.append(spec(name, "edge", mesh_sites.site_of(i), None if trust.keys is None else name, edge,
                          listens=tuple(edge_endpoints[i]), connects=(*connects, *mesh), namespace=ns))

    def client(name: str, role: str, config: Callable[[dict[str, Any]], BaseModel], main_namespace: bool = False,
               env: dict[str, str] | None = None) -> None:
        site = site_of(name)
        connects = uplink(role, site)
        procs.append(spec(name, role, site, None if trust.keys is None else role,
                          config(session(o, trust, connects, client_lease)), connects=tuple(connects),
                          env=dict(env or {}), namespace=site if netns and not main_namespace else None))

    client("planner", "planner", lambda bus: planner_config(o, bus))
    n = o.detectors  # N instances share the cameras by UAV id (services.detector.partition)
    for k in range(n):
        client("detector" if n == 1 else f"detector-{k}", "detector", lambda bus, k=k: detector_config(o, bus, k, n))
    if o.video:  # skynet video: RTP/UDP to loopback, UAV 1 on 5600 (services.video)
        client("video", "video", lambda bus: video_config(o, bus), main_namespace=True)
    if o.web and not ground_station:  # skynet up: the page as its own process, its token in its environment
        client("web", "web", lambda bus: web_config(o, bus), main_namespace=True, env={WEB_TOKEN_ENV: web_token})
    if ground_station:  # skynet mission: the ground station runs in the launcher's own process
        connects = uplink("gcs", 0)
        procs.append(ProcessSpec("gcs", "gcs", 0, None if trust.keys is None else "gcs", (), tuple(connects),
                                 ready=False, in_process=True))
    return NetworkPlan(o.fleet, procs, proxies, files, site_endpoints, checked, trust, load, ground_station, launch)
