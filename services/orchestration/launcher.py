"""The embedded default: the whole network on one machine, as separate processes on loopback.

``skynet up`` starts the gateway, N edges (SkyNet peers), the planner and the detector on free
loopback ports, prefixes each service's log lines with its name, and stops everything cleanly
on Ctrl-C (SIGINT to every child so sessions close, then SIGTERM/SIGKILL for stragglers).

``skynet mission`` does the same, then runs the ground station's mission on the scenario in
this process (a Zenoh client, with the live progress display) and writes the report; its exit
status is the mission's.

Impairment experiments (link names and grammar in :mod:`services.orchestration.topology`):
``--impair NAME[/udp|/tcp]=SPEC`` puts user-space netem proxies (:mod:`services.netem`, a TCP and
a UDP one per link) on the named links: ``uavN``, ``planner``, ``detector``, ``gcs`` (that node's
uplink to the gateway — for an edge, the paper's 4G hop), ``uavI-uavJ`` (a SkyNet link between
two edges), ``uplinks``, ``skynet``, ``all``; ``/udp`` or ``/tcp`` impairs only the best-effort
or the reliable link. Shared memory stays off so that nothing bypasses the proxies. With
``--mesh proxied`` (the default as soon as a SkyNet link is impaired or faulted) the edges do
not dial each other from gossip; edge i connects to a proxy pair in front of edge j's listen
endpoints for every j > i. ``--no-recovery`` makes capture frames unrecoverable (edges publish
imagery without the recovery cache, the detector subscribes without recovery).

Faults (:mod:`services.orchestration.faults`): ``--fault "20s kill gateway for 3s"``, ``"25s kill uav3"``,
``"15s cut uplinks for 8s"``, ``"15s partition uav1-uav2 for 10s"``; AT counts from the
mission phase (``skynet mission``) or the network start (``skynet up``). A killed service is
restarted with the same command line and ports; the launcher puts clean proxies on the links a
fault cuts.

A service that exits by itself (a crash, not a fault's kill) is restarted by the supervisor
(:meth:`Network.start_supervisor`) with the same command line, after an exponential back-off
(:mod:`services.orchestration.restart`: 0.5 s doubling to 30 s, reset after 10 s of good run); each restart is
logged and, in a mission, recorded as the supervisor's (``supervisor-restart``), apart from injected faults. A
service that exits :data:`START_ATTEMPTS` times without ever printing its ready line cannot start: it is not
restarted again, its reason (its last error line) is logged, and ``skynet mission``, which waits for the
services it asked for (planner, detector, video) before the flight, fails with that reason in the report's
outcome. The network is never stopped because one service ended.

Attaching (:mod:`services.orchestration.attach`): while it runs, the network is described in
``.skynet/network.json`` (``--network FILE``), where ``skynet web``, ``skynet video`` and ``skynet replay`` find
it when given no endpoint.

Several gateways (:mod:`services.orchestration.sites`): ``--sites S`` starts one gateway per
site (``gateway``, ``gateway-1`` .. ``gateway-{S-1}``, ids ``gw0`` ..), each dialling the lower-numbered
ones over the same kind of link as the uplinks (TLS by default: a gateway's certificate, common name
``gateway``, passes the other's ACL as the role ``gateway``); formation g's edges attach to site ``g % S``,
the ground station to site 0, the planner and detector instances to site 0 unless ``--rcu-site NAME=K``.
``kill gateway`` and the restart of a gateway name site 0's; another site's is ``gateway-K`` to the supervisor.

Secure by default (:mod:`services.orchestration.trustmode`): a development key set (``--keys DIR``, else
``$SKYNET_KEYS`` or ``.keys/dev``), mutual TLS on a TLS multilink pair, access control by certificate common
name on the gateway and on each edge, commands and heartbeats signed by the ground station, in every mode:
proxied (impaired, fault-injected) links carry the same TLS sessions through TCP proxies; ``--insecure``
turns everything off.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import shutil
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from protocol import keys
from protocol.bus import Bus, BusConfig, endpoint_address, multilink_endpoints, setup_logging, stop_event_on_signals

from . import attach, trustmode
from . import sites as sitemap
from .faults import FaultInjector, Resolved, cut_links, plan_faults
from .process import ProcessGroup, free_port, free_port_pair
from .restart import RestartTracker

#: what the mission's record calls a restart made by the launcher's supervisor, and a service that could not
#: start (``FaultRecord.action``; reported apart from injected faults, services.gcs.resilience)
SUPERVISOR_RESTART = "supervisor-restart"
START_FAILED = "start-failed"
from edge.board import niceness
from edge.neighbourhood import FORMATION_SIZE
from edge.runtime import CAPTURE_LINKS, frame_size
from protocol.checks import rate_arg

from ..gateway.ingress import STATE_INGRESS_HZ
from .fleet_load import EDGE_NICE, GCS_STATE_BUDGET, NICE_ABOVE, PREVIEW_BUDGET, fleet_load
from .topology import (
    CLASSES,
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
#: the line each service prints when it is up (waited for after a restart)
READY = {"gateway": "router up", "planner": "planner up", "detector": "detector up", "video": "video up",
         "web": "web up"}
EDGE_READY = "board up"
#: the link lease of the gateway and the clients (planner, detector, ground station) when links are
#: proxied, s: the edges' own (edge.board, 2 s). Each side of
#: a zenoh link declares it dead after the *other* side's lease without news; with zenoh's default
#: (10 s) on the gateway, an uplink cut for 3 s left the edges on their old session while the
#: gateway had already dropped it, and after the restore the gateway refused their data ("Route
#: data with unknown scope") for good. With equal leases both sides drop the session and reopen.
GATEWAY_LEASE_S = 2.0
#: how long a restarted service may take to come up (the gateway retries a busy port meanwhile)
RESTART_TIMEOUT_S = 30.0
#: a service that exits this many times in a row without ever coming up cannot start (not restarted again)
START_ATTEMPTS = 3
#: how long ``skynet mission`` waits for the requested services to come up before the flight, s
START_TIMEOUT_S = 90.0


def ready_line(name: str) -> str | None:
    """The line service ``name`` prints once it is up (``uavN``: its board; ``detector-K``: a detector)."""
    if name.startswith("uav") and name[3:].isdigit():
        return EDGE_READY
    return READY.get(name.split("-")[0])


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


def _port_of(endpoint: str) -> int:
    """The port of a Zenoh endpoint such as ``tls/127.0.0.1:7447?rel=1``."""
    return int(endpoint_address(endpoint).rsplit(":", 1)[1])


def make_plan(args: argparse.Namespace, ground_station: bool) -> Plan:
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


class Network:
    """The processes of one run, the proxies on its links and the endpoints each node connects to.

    ``ground_station``: the run has an in-process GCS (``skynet mission``), whose uplink can be
    impaired. :meth:`kill`, :meth:`restart` and :meth:`link_proxies` are what the fault injector
    acts on.
    """

    def __init__(self, args: argparse.Namespace, echo=sys.stdout, log_dir: Path | None = None,
                 ground_station: bool = False, plan: Plan | None = None):
        self.args = args
        self.ground_station = ground_station
        self.plan = plan or make_plan(args, ground_station)
        #: --netns: one network namespace per site (services.orchestration.netns), opened by start()
        self.ns = None
        #: the fleet-size defaults: the ground station's state feed, previews, the edges' priority
        self.load = fleet_load(args.uavs, getattr(args, "gcs_state_hz", None), getattr(args, "preview_hz", None),
                               getattr(args, "edge_nice", None))
        #: transport/unicast/open_timeout of nodes whose links are proxied, ms (slower links, longer)
        self.open_timeout = open_timeout_ms(self.plan.impair.worst_delay_ms())
        self.group = ProcessGroup(echo=echo)
        self.log_dir = log_dir
        #: link name -> {"tcp": TcpProxy, "udp": UdpProxy}
        self.proxies: dict[str, dict] = {}
        #: TLS, certificate ACL, signed commands: secure by default, impaired or not (services.orchestration.trustmode)
        self.trust = trustmode.resolve(args, proxied=bool(self.plan.proxied))
        #: the listen endpoints of each site's gateway (site 0: the ground station's)
        self.site_endpoints = [self.endpoint_pair() for _ in self.plan.sites.sites]
        self.gateway_endpoints = self.site_endpoints[0]
        self.edge_endpoints: dict[int, list[str]] = {}
        self.epoch = time.time() + 3.0
        self.tmp = Path(tempfile.mkdtemp(prefix="skynet-net-"))
        self.injector: FaultInjector | None = None
        #: restarts the supervisor made: {"service", "code", "failures", "delay_s", "at"}
        self.restarts: list[dict] = []
        #: told of each restart (name, text); a mission sets its runner's ``note_fault`` here
        self.on_restart = None
        self._sup_stop = threading.Event()
        self._sup: threading.Thread | None = None
        #: the running network's description file (:meth:`describe`), None until written
        self.description: Path | None = None
        #: services that cannot start ({name: reason}, :meth:`start_failed`); told to ``on_start_failure``
        self.start_failures: dict[str, str] = {}
        self.on_start_failure = None

    # -- links
    def endpoint_pair(self) -> list[str]:
        """A node's listen endpoints: the TLS pair, or TCP + UDP."""
        if self.trust.tls:
            return trustmode.tls_endpoints(HOST, free_port(), free_port())
        return multilink_endpoints(HOST, *free_port_pair())

    def topology(self) -> list[str]:
        """One line per site: its gateway, where it listens and dials, and the nodes attached to it."""
        out = []
        for site in self.plan.sites.sites:
            dials = ", ".join(sitemap.gateway_process(j) for j in self.plan.sites.peers_of(site.index))
            nodes = [*(f"uav{u}" for u in site.uavs), *(["gcs"] if site.index == 0 and self.ground_station else []),
                     *site.rcus]
            out.append(f"site {site.index}: {sitemap.gateway_process(site.index)} at "
                       f"{' '.join(self.site_endpoints[site.index])}" + (f" dialling {dials}" if dials else "")
                       + f"; attached: {' '.join(nodes) or 'nothing'}")
        return out

    def key_args(self) -> list[str]:
        return [] if self.trust.keys is None else ["--keys", str(self.trust.keys)]

    def _proxy_pair(self, link: str, target: list[str]) -> list[str]:
        """Start the proxies of ``link`` in front of ``target`` (a multilink endpoint pair); the endpoints to
        connect to instead. A TLS pair (the default secure mode) gets two TCP proxies: the TLS session runs end
        to end through them, so the link keeps its encryption, its certificates and the ACL; the best-effort
        class ("udp" in an impairment) is then a TLS stream too, where loss is retransmission delay."""
        from services.netem.proxy import TcpProxy, UdpProxy

        tcp_target, udp_target = (endpoint_address(e) for e in target)
        tls = all(e.startswith("tls/") for e in target)
        seed = self.args.seed
        tp = TcpProxy((HOST, 0), tcp_target, self.plan.impair.spec(link, "tcp"),
                      seed=link_seed(seed, link, "tcp")).start()
        self.proxies[link] = {"tcp": tp}
        up = (TcpProxy if tls else UdpProxy)((HOST, 0), udp_target, self.plan.impair.spec(link, "udp"),
                                             seed=link_seed(seed, link, "udp")).start()
        self.proxies[link]["udp"] = up
        return self._proxied_ends(link)

    def _proxied_ends(self, link: str) -> list[str]:
        """The endpoints of ``link``'s proxies, TLS when its proxies are both TCP."""
        tp, up = self.proxies[link]["tcp"], self.proxies[link]["udp"]
        if up.kind == "tcp":
            return trustmode.tls_endpoints(HOST, tp.port, up.port)
        return multilink_endpoints(HOST, tp.port, up.port)

    def site_of(self, name: str) -> int:
        """The site whose gateway ``name`` attaches to: a UAV its formation's (``uavN``), an RCU (``planner``,
        ``detector``, ``detector-K``) its ``--rcu-site``, the ground station and the rest site 0."""
        m = self.plan.sites
        if name.startswith("uav") and name[3:].isdigit():
            return m.site_of(int(name[3:]))
        if name == "detector":  # also the instances' shared link name: make_plan keeps a proxied one at one site
            return min((s.index for s in m.sites for r in s.rcus if r.startswith("detector")), default=0)
        try:
            return m.site_of(name)
        except KeyError:
            return 0

    def endpoints_for(self, name: str, site: int | None = None) -> list[str]:
        """Where ``name`` connects: its site's gateway (``site``, default :meth:`site_of`), or the proxies of
        its uplink."""
        target = self.site_endpoints[self.site_of(name) if site is None else site]
        if name not in self.plan.proxied:
            return target
        if name not in self.proxies:
            self._proxy_pair(name, target)
        return self._proxied_ends(name)

    def link_proxies(self, link: str) -> list:
        """The proxies of a link (TCP then UDP); KeyError if the link has none."""
        if link not in self.proxies:
            raise KeyError(f"link {link!r} has no proxies (proxied: {', '.join(sorted(self.proxies)) or 'none'})")
        return [self.proxies[link][c] for c in CLASSES]

    def proxy_stats(self) -> dict[str, dict[str, dict]]:
        return {link: {c: p.stats() for c, p in pair.items()} for link, pair in self.proxies.items()}

    def bus_args(self, name: str, mode: str, site: int | None = None) -> list[str]:
        args = ["--mode", mode, "--fleet", self.args.fleet, "--multilink"]
        if self.plan.proxied and mode == "client":
            # equal leases on both ends (see GATEWAY_LEASE_S), a short open timeout (see client_cfg)
            args += ["--lease", str(GATEWAY_LEASE_S), *[a for k, v in self.client_cfg() for a in ("--cfg", f"{k}:{v}")]]
        for e in self.endpoints_for(name, site):
            args += ["--connect", trustmode.gateway_dial(e, self.trust.keys)]
        return args + self.key_args()

    def client_cfg(self) -> list[tuple[str, str]]:
        """The zenoh config change of the clients (planner, detector, ground station) when links are proxied
        (``--cfg``): the edges' open timeout (:data:`services.orchestration.topology.OPEN_TIMEOUT_MS`), so
        that a UDP handshake lost on an impaired link after a gateway restart is retried in seconds, not
        after zenoh's 10 s."""
        return [("transport/unicast/open_timeout", json.dumps(self.open_timeout))]

    def edge_config(self, i: int) -> list[str]:
        """``--config FILE`` of edge ``i``: the secured mesh's dictionary and/or the gossip autoconnect
        rules that keep its links on the proxies (:func:`services.orchestration.topology.edge_mesh_config`).
        A file (mode 0600)."""
        # several formations: no gossip autoconnect, or every edge would dial every other
        formations = self.args.uavs > FORMATION_SIZE
        if self.plan.mesh == "direct" and f"uav{i}" not in self.plan.proxied and not formations:
            return []
        base = None
        path = self.tmp / f"uav{i}.json5"
        mesh = "proxied" if formations else self.plan.mesh  # proxied: autoconnect to nothing
        path.write_text(json.dumps(edge_mesh_config(mesh, base, self.open_timeout)))
        path.chmod(0o600)
        return ["--config", str(path)]

    def mesh_connect(self, i: int) -> list[str]:
        """Edge i's ``--connect`` to every edge j > i of its formation: through the proxies in front of j with the
        proxied mesh, else straight to j's endpoints. Dialled endpoints are retried until they
        answer, while a peer learned by gossip is dialled when the gossip arrives: an edge that
        was not listening yet then stayed out of the mesh for good (seen under load in CI)."""
        from edge.neighbourhood import members

        out = []
        for j in (j for j in members(i, fleet=self.args.uavs) if j > i):  # its formation only
            ends = (self._proxy_pair(skynet_link(i, j), self.edge_endpoints[j]) if self.plan.mesh == "proxied"
                    else self.edge_endpoints[j])
            for e in ends:
                out += ["--connect", e]
        return out

    # -- services
    def start_service(self, name: str, args: list[str], user: str | None = None):
        """Start a service (in its site's namespace with --netns); ``user`` is the identity it runs as (unused: the
        key set gives each service its certificate by role)."""
        return self.group.start(name, args, prefix=self.prefix_of(name), ready=ready_line(name))

    #: services that stay in the machine's own namespace with --netns (what a user reaches from here)
    MAIN_NAMESPACE = ("web", "video")

    def prefix_of(self, name: str) -> list[str]:
        """The command that runs ``name`` in its site's namespace (--netns), else none."""
        if self.ns is None or name in self.MAIN_NAMESPACE:
            return []
        return self.ns.prefix(self.site_of(name))

    def start_ready(self, name: str, args: list[str], ready: str, prefix: list[str] | None = None):
        """Start a process of the network's own plumbing (gateway, namespace proxy or bridge) and wait up to
        30 s for its ``ready`` line; RuntimeError with its last lines if it does not come up."""
        svc = self.group.start(name, args, prefix=prefix)
        if not svc.wait_for(ready, 30):
            raise RuntimeError(f"{name} did not start:\n" + "\n".join(svc.lines[-20:]))
        return svc

    def netns_router_link(self, site: int, peer: int) -> list[str]:
        """--netns: gateway ``site`` dials gateway ``peer`` through the project's TCP proxy (``skynet netem tcp``,
        in ``site``'s namespace, on its loopback) to ``peer``'s veth address: the TLS session runs end to end and
        is checked against 127.0.0.1, the name in the key set's certificates. The endpoints to dial."""
        out = []
        for e in self.site_endpoints[peer]:
            port = _port_of(e)
            local = free_port()
            target = f"{self.ns.address(peer, site).split('/')[0]}:{port}"
            self.start_ready(f"link-{sitemap.gateway_process(site)}-{sitemap.gateway_process(peer)}-{port}",
                             ["netem", "tcp", "--listen", f"{HOST}:{local}", "--target", target, "--interval", "60"],
                             "netem tcp listening", prefix=self.ns.prefix(site))
            out.append(e.replace(f"{HOST}:{port}", f"{HOST}:{local}"))
        return out

    def netns_bridges(self) -> None:
        """--netns: site 0's gateway reached from the machine's own namespace (the ground station, skynet web,
        a user's tools) at its own endpoints: a Unix socket bridge inside site 0 and one outside it
        (:mod:`services.orchestration.bridge`), carrying the TLS session end to end."""
        for e in self.site_endpoints[0]:
            port = _port_of(e)
            sock = self.tmp / f"gateway-{port}.sock"
            self.start_ready(f"bridge-in-{port}", ["bridge", "--listen", f"unix:{sock}", "--target",
                                                   f"tcp:{HOST}:{port}"], "bridge up", prefix=self.ns.prefix(0))
            self.start_ready(f"bridge-out-{port}", ["bridge", "--listen", f"tcp:{HOST}:{port}", "--target",
                                                    f"unix:{sock}"], "bridge up")

    def gcs_config(self) -> BusConfig:
        """The in-process ground station's session."""
        lease = {"lease_s": GATEWAY_LEASE_S, "cfg": self.client_cfg()} if self.plan.proxied else {}
        tls = {}
        if self.trust.keys is not None and self.trust.tls:
            from protocol.keyset import KeySet
            ks = KeySet(self.trust.keys, "gcs")
            tls = {"tls_ca": str(ks.tls_ca), "tls_cert": str(ks.tls_cert), "tls_key": str(ks.tls_key)}
        connect = [trustmode.gateway_dial(e, self.trust.keys) for e in self.endpoints_for("gcs")]
        return BusConfig(mode="client", connect=connect, multilink=True, **lease, **tls)

    def gcs_signer(self):
        """The ground station's signer (None: --insecure, unsigned commands)."""
        if self.trust.keys is None:
            return None
        from protocol.keyset import KeySet
        return KeySet(self.trust.keys, "gcs").signer()

    def plan_verifier(self):
        """The ground station's verifier of the planner's signed plans (None without a key set)."""
        if self.trust.keys is None:
            return None
        from services.gcs.cli import plan_verifier_of
        return plan_verifier_of(self.trust.keys)

    def homes(self, n: int) -> list[tuple[float, float, float]]:
        """Launch points: the formation slots around the start, on the ground (P9); a UAV stacked
        above another launches beside it (:func:`edge.formation.home_offsets`)."""
        from edge.formation import home_offsets, offsets_for, rotation_of
        from protocol.scenario import load_scenario

        sc = load_scenario(self.args.scenario)
        start, goal = sc.start, sc.goal
        yaw = math.atan2(goal[1] - start[1], goal[0] - start[0])
        R = rotation_of(0.0, 0.0, yaw)
        ground = sc.box.lo[2]
        out = []
        for xy in home_offsets(offsets_for(n)):
            p = (R @ (xy[0], xy[1], 0.0))[:2]
            out.append((round(start[0] + p[0], 3), round(start[1] + p[1], 3), ground))
        return out

    def gateway_config(self) -> list[str]:
        """The gateways' traffic options: ``--state-ingress-hz`` when given (else the gateway's default per-face
        limit, :mod:`services.gateway.ingress`), and with ``--gcs-state-hz`` a ``--cfg downsampling:[...]`` that
        thins the clients' view of the states (:mod:`services.gateway.downsample`)."""
        ingress = getattr(self.args, "state_ingress_hz", None)  # None: the gateway's default limit
        out = [] if ingress is None else ["--state-ingress-hz", str(ingress)]
        hz = self.load.gcs_state_hz
        if hz <= 0:
            return out
        from ..gateway.downsample import state_downsampling

        rules = state_downsampling(self.args.fleet, hz, self.args.uavs)
        return out + [a for k, v in rules.items() for a in ("--cfg", f"{k}:{json.dumps(v)}")]

    def start(self) -> None:
        a = self.args
        for w in self.trust.warnings:
            logging.getLogger("skynet.launcher").warning("%s", w)
        lease = ["--lease", str(GATEWAY_LEASE_S)] if self.plan.proxied else []
        thin = self.gateway_config()
        if getattr(a, "netns", False):
            from .netns import Namespaces, available

            ok, why = available()
            if not ok:
                raise RuntimeError(f"--netns: no network namespaces here: {why}")
            self.ns = Namespaces(self.plan.sites).open()
        for site in self.plan.sites.sites:  # one gateway per site, each dialling the lower-numbered ones
            name = sitemap.gateway_process(site.index)
            ident = [] if len(self.site_endpoints) == 1 else ["--id", site.gateway]
            peers = self.plan.sites.peers_of(site.index)
            targets = ([e for j in peers for e in self.netns_router_link(site.index, j)] if self.ns is not None
                       else [e for j in peers for e in self.site_endpoints[j]])
            listen = self.site_endpoints[site.index]
            if self.ns is not None:  # also on its veths, for the router links' proxies
                listen = [e.replace(f"/{HOST}:", "/0.0.0.0:") for e in listen]
            self.start_ready(name, ["gateway", *ident, "--fleet", a.fleet, "--multilink", *lease, *thin,
                                    *(["--accept-guard"] if getattr(a, "accept_guard", False) else []),
                                    *self.key_args(),
                                    *[x for e in targets for x in ("--connect", trustmode.gateway_dial(e, self.trust.keys))],
                                    *[x for e in listen for x in ("--listen", e)]],
                             READY["gateway"], prefix=[] if self.ns is None else self.ns.prefix(site.index))
            if self.ns is not None and site.index == 0:
                self.netns_bridges()
        if len(self.site_endpoints) > 1:
            for line in self.topology():
                logging.getLogger("skynet.launcher").info("%s", line)
        scenario = ["--scenario", a.scenario] if a.scenario else []
        recovery = ["--imagery-cache", "0"] if getattr(a, "no_recovery", False) else []
        preview = ["--preview-hz", f"{self.load.preview_hz:g}"]
        nice = ["--nice", str(self.load.edge_nice)] if self.load.edge_nice else []
        if self.load.chosen:
            logging.getLogger("skynet.launcher").info("%d UAVs on one machine: %s", a.uavs, "; ".join(self.load.chosen))
        for i in range(1, a.uavs + 1):
            self.edge_endpoints[i] = self.endpoint_pair()
        for i, home in enumerate(self.homes(a.uavs), start=1):
            vehicle = []
            if getattr(a, "vehicle", "sim") == "mavlink":  # a sim autopilot per UAV, on loopback UDP
                port = free_port_pair()[1]
                self.group.start(f"ap{i}", ["sim-autopilot", "--uav", str(i), "--port-base", str(port - i + 1),
                                            "--home", ",".join(map(str, home)), "--speed", str(a.speed),
                                            "--epoch", str(self.epoch), "--seed", str(a.seed + i), "--wind", "moderate",
                                            "--boot-scale", f"{getattr(a, 'autopilot_boot_scale', 1.0):g}",
                                            "--firmware-version", getattr(a, "autopilot_firmware", "4.6")],
                                 prefix=self.prefix_of(f"uav{i}"))  # beside its edge
                vehicle = ["--vehicle", "mavlink", "--mavlink", f"udpin:{HOST}:{port}",
                           "--flight", getattr(a, "flight", "guided")]
            self.start_service(f"uav{i}", [
                "edge", "--uav", str(i), *self.bus_args(f"uav{i}", "peer"), *self.mesh_connect(i),
                *self.edge_config(i), *[x for e in self.edge_endpoints[i] for x in ("--listen", e)],
                "--home", ",".join(map(str, home)), "--speed", str(a.speed), "--epoch", str(self.epoch),
                "--seed", str(a.seed + i), "--camera", a.camera, "--frame-size", getattr(a, "frame_size", "640x480"),
                "--capture-link", getattr(a, "capture_link", "auto"), *preview, *nice, *scenario, *recovery,
                *vehicle])
        # a large fleet's plan is computed while its edges load the machine: the planner may
        # take up to 100 s of the ground station's 120 s plan timeout instead of its own 60 s default,
        # and then answers with the best collision-free path it found (48 edges left it 157 of 300 iterations)
        budget = ["--time-budget", "100", "--anytime"] if a.uavs > 24 else []
        self.start_service("planner", ["planner", *self.bus_args("planner", "client"), *budget])
        no_recovery = ["--no-recovery"] if getattr(a, "no_recovery", False) else []
        save = ["--save-frames", a.save_frames] if getattr(a, "save_frames", None) else []
        n = getattr(a, "detectors", 1)  # N instances share the cameras by UAV id (services.detector.partition)
        for k in range(n):
            part = [] if n == 1 else ["--partition", f"{k}/{n}", "--max-uav", str(a.uavs)]
            name = "detector" if n == 1 else f"detector-{k}"
            self.start_service(name,
                               ["detector", *self.bus_args("detector", "client", self.site_of(name)),
                                "--method", a.method,
                                *part, *no_recovery, *save, *self.detect_args()], user="detector")
        if getattr(a, "video", None):  # skynet video: RTP/UDP to loopback, UAV 1 on 5600 (services.video)
            self.start_service("video", ["video", *self.bus_args("video", "client"), "--codec", a.video,
                                         "--uavs", str(a.uavs), "--sdp-dir", str(a.video_sdp),
                                         "--port", str(getattr(a, "video_port", 5600))])
        if getattr(a, "web", None) and not self.ground_station:  # skynet up: the page as its own process
            self.start_web_service(["web", *self.bus_args("web", "client"), "--listen-web", a.web, *scenario])

    def start_web_service(self, args: list[str]) -> None:
        """``skynet web`` with the page's token in its environment (the launcher's own ``SKYNET_WEB_TOKEN``,
        else random), so that the launcher prints the page's URL: :meth:`web_url`."""
        from services.web.server import TOKEN_ENV, new_token

        self.web_token = os.environ.get(TOKEN_ENV) or new_token()
        self.group.env[TOKEN_ENV] = self.web_token
        try:
            self.start_service("web", args)
        finally:
            self.group.env.pop(TOKEN_ENV, None)

    def web_url(self) -> str | None:
        """The URL of the page ``skynet up --web`` started, with its token (None without a page)."""
        from services.web.server import page_url, parse_listen

        token = getattr(self, "web_token", None)
        return None if token is None else page_url(*parse_listen(self.args.web), token)

    def detect_args(self) -> list[str]:
        """``--detect-max-mp`` for the detector when given (a large frame detected on a reduced decode)."""
        mp = getattr(self.args, "detect_max_mp", None)
        return [] if mp is None else ["--detect-max-mp", str(mp)]

    def start_faults(self, log: logging.Logger) -> FaultInjector | None:
        """The fault injector of ``--fault`` (None without faults), not started yet: ``start(origin)``
        with the wall time AT counts from, or ``attach(runner)`` then ``start()``."""
        if not self.plan.faults:
            return None
        self.injector = FaultInjector(self, self.plan.faults, log)
        return self.injector

    def kill(self, name: str) -> None:
        """SIGKILL a service (a crash)."""
        self.group.kill(name)

    def restart(self, name: str) -> float:
        """Start a killed service again with the same command line (same ports); the seconds until it
        said it is up. The gateway's ports may still be held for a moment: it is retried until
        :data:`RESTART_TIMEOUT_S`."""
        t0 = time.monotonic()
        ready = READY.get(name.split("-")[0], EDGE_READY)  # detector-K: an instance of the detector
        while True:
            svc = self.group.restart(name)
            left = RESTART_TIMEOUT_S - (time.monotonic() - t0)
            if svc.wait_for(ready, max(left, 0.1)):
                return time.monotonic() - t0
            if svc.alive() or time.monotonic() - t0 > RESTART_TIMEOUT_S:
                raise RuntimeError(f"{name} did not come back up:\n" + "\n".join(svc.lines[-10:]))
            time.sleep(0.2)  # it exited (e.g. its port still busy): try again

    def check_alive(self) -> list[str]:
        """Services that ended on their own (not those a fault killed)."""
        return [s.name for s in self.group.services if not s.alive() and not s.killed]

    def start_supervisor(self, log: logging.Logger, tracker: RestartTracker | None = None,
                         period_s: float = 0.2) -> None:
        """Restart services that end by themselves (see the module docstring), in a thread until :meth:`stop`."""
        tracker = tracker or RestartTracker()

        def loop() -> None:
            while not self._sup_stop.wait(period_s):
                try:
                    self.supervise(tracker, log)
                except Exception:  # the supervisor outlives a failed pass, and says so
                    log.exception("supervisor pass failed")

        self._sup = threading.Thread(target=loop, name="supervisor", daemon=True)
        self._sup.start()

    def supervise(self, tracker: RestartTracker, log: logging.Logger) -> None:
        """One pass: schedule the restart of services that ended on their own, start those that are due.

        A service that exits :data:`START_ATTEMPTS` times in a row without ever having come up (its ready
        line, :func:`ready_line`) cannot start: it is not restarted again, and :meth:`start_failed` says why
        (:attr:`start_failures`, :attr:`on_start_failure`). One that came up once and then ended crashed
        after working: it is restarted, and the restart is reported as the supervisor's, not as a fault."""
        if self.group.closed:
            return
        now = time.monotonic()
        for svc in list(self.group.services):
            if svc.alive() or svc.killed or tracker.pending(svc.name) or svc.name in self.start_failures:
                continue
            if svc.ready_text is not None and not svc.ever_ready and svc.restarts + 1 >= START_ATTEMPTS:
                self.start_failed(svc.name, f"exited {svc.restarts + 1} times without coming up, last with code "
                                            f"{svc.proc.returncode}: {svc.reason()}", log)
                continue
            p = tracker.exited(svc.name, now, now - svc.started, svc.proc.returncode)
            how = "before it came up" if svc.ready_text is not None and not svc.ever_ready else f"after {now - svc.started:.1f} s"
            log.error("%s exited with code %s %s (%s); restarting it in %.1f s (quick failure %d in a row)",
                      svc.name, p.code, how, svc.reason(), p.due - now, p.failures)
        for p in tracker.due(now):
            try:
                svc = self.group.restart(p.name)
            except RuntimeError:  # the group is stopping
                return
            text = f"exited with code {p.code}; restarted by the supervisor (run {svc.restarts + 1})"
            self.restarts.append({"service": p.name, "code": p.code, "failures": p.failures,
                                  "at": time.time(), "text": text})
            log.warning("%s %s", p.name, text)
            if self.on_restart is not None:
                self.on_restart(p.name, text)

    def describe(self) -> Path | None:
        """Leave the running network's description where the tools find it (:mod:`.attach`); removed by
        :meth:`stop`. A folder it cannot be written to is said, not fatal (None): the tools then need ``-e``."""
        path = attach.network_path(getattr(self.args, "network", None))
        desc = attach.describe(self.args.fleet, self.gateway_endpoints, self.trust.keys, self.trust.tls)
        try:
            self.description = attach.write(path, desc)
        except OSError as exc:
            logging.getLogger("skynet.launcher").warning(
                "could not describe the network in %s (%s): skynet web/video/replay need -e %s", path,
                exc.strerror or exc, " -e ".join(self.gateway_endpoints))
        return self.description

    def start_failed(self, name: str, reason: str, log: logging.Logger | None = None) -> None:
        """Note that ``name`` cannot start (not restarted again): :attr:`start_failures`, the log, the hook."""
        if name in self.start_failures:
            return
        self.start_failures[name] = reason
        (log or logging.getLogger("skynet.launcher")).error("%s did not start: %s", name, reason)
        if self.on_start_failure is not None:
            self.on_start_failure(name, reason)

    def wait_started(self, names: list[str], timeout_s: float, log: logging.Logger | None = None) -> dict[str, str]:
        """Wait until each of ``names`` came up or cannot start (the supervisor decides, :meth:`supervise`),
        at most ``timeout_s``; one still not up then cannot start either. The failures ({name: reason})."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not self.group.closed:
            pending = [n for n in names if n not in self.start_failures and not self.group.get(n).ever_ready]
            if not pending:
                break
            time.sleep(0.2)
        for n in names:
            if n not in self.start_failures and not self.group.get(n).ever_ready:
                self.start_failed(n, f"not up after {timeout_s:.0f} s ({self.group.get(n).reason()})", log)
        return {n: self.start_failures[n] for n in names if n in self.start_failures}

    def requested(self) -> list[str]:
        """The services a run asks for besides the edges: planner, detector(s), and video / web when asked."""
        n = getattr(self.args, "detectors", 1)
        out = ["planner", *(["detector"] if n == 1 else [f"detector-{k}" for k in range(n)])]
        if getattr(self.args, "video", None):
            out.append("video")
        if getattr(self.args, "web", None) and not self.ground_station:
            out.append("web")
        return out

    def stop(self) -> dict:
        if self.description is not None:
            attach.remove(self.description)
            self.description = None
        self._sup_stop.set()
        if self._sup is not None:
            self._sup.join(5.0)
        if self.injector is not None:
            self.injector.cancel()  # then the group refuses restarts and its stop ends a restart's wait
        codes = self.group.stop()
        if self.injector is not None:
            self.injector.stop()
        for pair in self.proxies.values():
            for p in pair.values():
                p.stop()
        if self.ns is not None:
            self.ns.close()
        shutil.rmtree(self.tmp, ignore_errors=True)
        return codes


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=f"skynet {prog}", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="Links: uavN, planner, detector" + (", gcs" if prog == "mission" else "")
                                + " (uplinks to the gateway), uavI-uavJ (SkyNet), uplinks, skynet, all.\n"
                                "Examples:\n"
                                '  --impair "all/udp=after 2s delay 200ms loss 20%"\n'
                                '  --impair uav2="delay 50ms jitter 10ms"   --impair uav1-uav2=loss 5%\n'
                                '  --fault "20s kill gateway for 3s"   --fault "15s cut uplinks for 8s"\n'
                                '  --fault "25s kill uav3"   --fault "15s partition uav1-uav2 for 10s"')
    p.add_argument("--uavs", type=int, default=3, help="number of UAVs")
    p.add_argument("--scenario", default=None, help="scenario file (default: the paper's monorail bridge)")
    p.add_argument("--speed", type=float, default=4.0, help="simulation speed factor (1 = real time)")
    p.add_argument("--camera", default="synthetic", help="synthetic | an image folder | video:<url>")
    p.add_argument("--frame-size", type=frame_size, default="640x480", help="capture frame size WxH (4000x3000: the paper's 12 MP)")
    p.add_argument("--preview-hz", type=rate_arg, default=None, metavar="HZ",
                   help=f"live preview frames per UAV per second (default: {PREVIEW_BUDGET:g} for the fleet, at most "
                        "the edge's 2 per UAV; 0 = off)")
    p.add_argument("--gcs-state-hz", type=rate_arg, default=None, metavar="HZ",
                   help=f"states per UAV per second the gateway forwards to the ground station (0: all, 20 Hz; "
                        f"default: all up to {GCS_STATE_BUDGET:g} for the fleet, else {GCS_STATE_BUDGET:g}/N)")
    p.add_argument("--netns", action="store_true",
                   help="each site in a network namespace of its own, as a stand-in for a host (root; "
                        "services/orchestration/netns.py): router links over veth pairs through skynet netem's "
                        "proxy, site 0 reached from here through a Unix socket bridge")
    p.add_argument("--edge-nice", type=niceness, default=None, metavar="N",
                   help=f"the edges' niceness (default: {EDGE_NICE} above {NICE_ABOVE} UAVs, else 0; "
                        "services/orchestration/fleet_load.py)")
    p.add_argument("--state-ingress-hz", type=rate_arg, default=None, metavar="HZ",
                   help=f"states per UAV key the gateway lets in from one session per second (default "
                        f"{STATE_INGRESS_HZ:g}; 0: no limit; services/gateway/ingress.py)")
    p.add_argument("--detect-max-mp", type=float, default=None, metavar="MP",
                   help="the detector detects frames above MP megapixels on a reduced decode (its default 1; 0: never)")
    p.add_argument("--capture-link", choices=CAPTURE_LINKS, default="auto",
                   help="link of capture frames: best-effort (UDP), reliable (TCP), auto: reliable above 1 MP")
    p.add_argument("--vehicle", choices=["sim", "mavlink"], default="sim",
                   help="sim: the built-in vehicle; mavlink: each edge flies a sim autopilot (skynet sim-autopilot) "
                        "over MAVLink on loopback")
    p.add_argument("--autopilot-boot-scale", type=float, default=1.0, metavar="F",
                   help="--vehicle mavlink: the sim autopilots' start-up times as a fraction of ArduCopter's "
                        "(1: GUIDED/AUTO after 42 simulated s; 0.1 ten times faster; 0 at once)")
    p.add_argument("--autopilot-firmware", choices=["4.6", "4.7"], default="4.6",
                   help="--vehicle mavlink: the sim autopilots' parameter names and units: 4.6 (stable 4.5/4.6: "
                        "WPNAV_SPEED cm/s, RTL_ALT cm, ...) or 4.7 (4.7+: WP_SPD m/s, RTL_ALT_M m, ...)")
    p.add_argument("--ready-timeout", type=float, default=120.0, metavar="S",
                   help="the ground station waits this long for every UAV's autopilot to be ready, then refuses")
    p.add_argument("--flight", choices=["guided", "auto"], default="guided",
                   help="--vehicle mavlink: guided (position targets) or auto (a waypoint mission flown in AUTO)")
    p.add_argument("--method", default="it+r", help="the detector's method")
    p.add_argument("--detectors", type=int, default=1, metavar="N",
                   help="detector instances sharing the cameras (detector-K analyses the UAVs with id %% N == K)")
    p.add_argument("--sites", type=int, default=1, metavar="S",
                   help="gateways: one per site, meshed (each dials the lower-numbered ones); formation g "
                        "(UAVs 3g+1..3g+3) attaches to site g %% S, the ground station to site 0 (1 <= S <= formations)")
    p.add_argument("--rcu-site", action="append", default=[], metavar="NAME=K",
                   help="attach an RCU to site K's gateway (repeatable; default site 0): planner, detector "
                        "(every instance) or detector-K")
    p.add_argument("--fleet", default=keys.DEFAULT_FLEET)
    p.add_argument("--seed", type=int, default=0, help="seeds the simulation and every proxy (per link)")
    p.add_argument("--impair", action="append", default=[], metavar="NAME[/udp|/tcp]=SPEC",
                   help="netem impairment on a link or group of links (repeatable, later wins), e.g. "
                        'uav2="delay 50ms loss 2%%"; SPEC as in skynet netem')
    p.add_argument("--mesh", choices=["direct", "proxied"], default=None,
                   help="direct: edges dial each other straight; proxied: through a proxy pair per "
                        "SkyNet link (default: proxied when a SkyNet link is impaired or faulted)")
    p.add_argument("--no-recovery", action="store_true",
                   help="capture frames not recoverable: no imagery cache on the edges, no recovery in the detector")
    p.add_argument("--fault", action="append", default=[], metavar='"AT ACTION TARGET [for D]"',
                   help="scripted fault (repeatable): kill gateway|uavN|planner|detector, cut uavN|uplinks|planner|"
                        "detector" + ("|gcs" if prog == "mission" else "") + ", partition uavI-uavJ|uavN|skynet; "
                        "AT from the " + ("mission phase" if prog == "mission" else "network start"))
    p.add_argument("--keys", default=None, metavar="DIR",
                   help=f"fleet key set (skynet keys init); default: a development set in ${trustmode.KEYS_ENV} or {trustmode.DEFAULT_KEYS}")
    p.add_argument("--accept-guard", action="store_true",
                   help="the gateways accept TLS connections through a guard that drops those not starting a TLS "
                        "handshake (connect-and-close or silent floods; services/gateway/guard.py, bench/accept.py)")
    p.add_argument("--insecure", action="store_true",
                   help="no TLS, no access control, unsigned commands: development only")
    p.add_argument("--video", choices=["h264", "mjpeg"], default=None,
                   help="also run skynet video: each UAV's preview as RTP/UDP to 127.0.0.1:PORT+2(n-1) (--video-port)")
    p.add_argument("--video-sdp", default="sdp", help="folder of the video streams' SDP files (with --video)")
    p.add_argument("--video-port", type=int, default=5600, metavar="PORT",
                   help="UAV 1's preview port (with --video); UAV n's is PORT + 2(n-1)")
    p.add_argument("--web", default=None, metavar="[HOST]:PORT",
                   help="serve the live web page of the fleet there, e.g. :8080 (loopback unless a host is given)")
    p.add_argument("--network", default=None, metavar="FILE",
                   help=f"where to describe the running network for skynet web/video/replay (default: "
                        f"${attach.NETWORK_ENV} or {attach.NETWORK_FILE}; removed at the end)")
    if prog == "mission":
        p.add_argument("--out", default=None, help="report folder (default reports/mission-<time>)")
        p.add_argument("--quiet", action="store_true", help="no live progress display")
        p.add_argument("--algorithm", default="theta-pso")
        p.add_argument("--no-record", action="store_true", help="do not log the mission to OUT/mission.mcap")
    return p


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    prog = argv.pop(0) if argv and argv[0] in ("up", "mission") else "up"
    parser = build_parser(prog)
    args = parser.parse_args(argv)
    try:
        plan = make_plan(args, ground_station=prog == "mission")
    except ValueError as e:
        parser.error(str(e))
    log = setup_logging(prog)
    stop = stop_event_on_signals()
    if prog == "up":
        net = Network(args, plan=plan)
        try:
            net.start()
            log.info("network up: gateway at %s; Ctrl-C to stop", " ".join(net.gateway_endpoints))
            if net.web_url():
                log.info("web page at %s", net.web_url())
            for link in sorted(net.proxies):
                log.info("proxies on %s: tcp %s, udp %s", link, *(net.proxies[link][c].port for c in CLASSES))
            injector = net.start_faults(log)
            if injector is not None:
                injector.start(origin=time.time())
            net.start_supervisor(log)  # a service that ends is restarted, the network stays up
            described = net.describe()
            if described is not None:
                log.info("network described in %s: `skynet web`, `skynet video`, `skynet replay FILE` attach to it "
                         "from this folder with no options", described)
            while not stop.wait(1.0):
                pass
        finally:
            codes = net.stop()
            log.info("stopped: %s", codes)
        return 0
    return run_mission(args, log, stop, plan)


def run_mission(args: argparse.Namespace, log: logging.Logger, stop, plan: Plan | None = None) -> int:
    from protocol.scenario import load_scenario
    from services.gcs.cli import run_mission as gcs_mission
    from services.gcs.mission import MissionOptions
    from services.gcs.record import check_output_folder

    # not writable or too little room: refused (RecordingError) before any service starts
    out = check_output_folder(args.out or f"reports/mission-{time.strftime('%Y%m%d-%H%M%S')}")
    log_file = open(out / "services.log", "w")
    args.save_frames = str((out / "frames").resolve())  # the captures, for the inspection deliverable
    net = Network(args, echo=log_file, ground_station=True, plan=plan)
    scenario = load_scenario(args.scenario)
    try:
        net.start()
        net.describe()
        cfg = net.gcs_config()
        hooks_signer = net.gcs_signer()
        # every edge imports and starts at once on the same cores: 48 of them took over 30 s to appear
        options = MissionOptions(uavs=tuple(range(1, args.uavs + 1)), algorithm=args.algorithm, seed=args.seed,
                                 speed=args.speed, appear_timeout_s=max(30.0, 2.5 * args.uavs),
                                 ready_timeout_s=args.ready_timeout)
        injector = net.start_faults(log)

        def on_runner(runner) -> None:
            net.on_restart = lambda name, text: runner.note_fault(SUPERVISOR_RESTART, name, text)

            def start_failure(name: str, reason: str) -> None:
                runner.note_fault(START_FAILED, name, reason)
                with runner._lock:
                    runner.record.failures.append(f"{name} did not start: {reason}")

            for r in list(net.restarts):  # made before the runner was (while the services came up)
                runner.note_fault(SUPERVISOR_RESTART, r["service"], r["text"])
            for name, reason in dict(net.start_failures).items():
                start_failure(name, reason)
            net.on_start_failure = start_failure
            # the services asked for, before the flight; the runner listens already (the edges' first events)
            failed = net.wait_started(net.requested(), START_TIMEOUT_S + 2.0 * args.uavs, log)
            if failed:
                log.error("the mission will fail: %s", "; ".join(f"{n} did not start ({r})" for n, r in failed.items()))
            if injector is not None:
                injector.attach(runner)
                injector.start()

        hooks = {"on_runner": on_runner}
        net.start_supervisor(log)
        with Bus(cfg, fleet=args.fleet, name="gcs") as bus:
            web_server = None
            if args.web:  # the live page in the ground station's process, with its plan (services.web)
                from services.web.service import follow_runner, start_web

                view, web_server = start_web(bus, args.web, scenario, log=log, frames=args.save_frames)
                before = hooks.get("on_runner")
                hooks["on_runner"] = lambda runner: (before and before(runner),
                                                     follow_runner(view, runner, tally=web_server.tally))
            try:
                code = gcs_mission(bus, scenario, options, str(out), args.quiet, log, abort=stop,
                                   ground_truth=args.camera == "synthetic", signer=hooks_signer,
                                   plan_verifier=net.plan_verifier(),
                                   record=not args.no_record, **hooks)
            finally:
                if web_server is not None:
                    web_server.stop()
        if net.proxies:
            (out / "proxies.json").write_text(json.dumps(net.proxy_stats(), indent=1))
        if net.restarts:
            (out / "restarts.json").write_text(json.dumps(net.restarts, indent=1))
    finally:
        net.stop()
        log_file.close()
    log.info("services' logs: %s", out / "services.log")
    return code
